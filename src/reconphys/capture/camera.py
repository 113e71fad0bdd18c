"""The camera of a recording: a JSON file, or the default (the dataset's view 0).

Camera file (``--camera cam.json``; OpenCV convention, docs/design.md#conventions)::

    {
      "K": [[fx, 0, cx], [0, fy, cy], [0, 0, 1]],       pixels, at the size given below
      "world_to_cam": [[...4 numbers...] × 4],          metres, world z up, ground z = 0
      "width": 1920, "height": 1080,                    optional: the size K refers to
      "ground_height": 0.0                               optional, metres (default 0)
    }

When ``width``/``height`` differ from the video's, K is scaled to the video (the same shape
within 5 %: MAX_ASPECT_CHANGE; a turned or cropped video is refused). A file with K and
no ``world_to_cam`` (a checkerboard calibration without a floor marker) gives the intrinsics
alone: the pose and the ground are then read from the video (:func:`read_intrinsics`).
``--camera dataset`` is the dataset's view 0 (2 m from the point (0, 0, 0.3) m, 15° elevation,
40° vertical field of view) at the video's size.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass

import torch
from torch import Tensor

from ..errors import InputError
from ..io import atomic_file, read_json
from ..render import Cameras


@dataclass
class CameraSpec:
    """One pinhole camera at a given image size, and the ground plane."""

    K: Tensor  # [3, 3] pixels at (width, height)
    world_to_cam: Tensor  # [4, 4] metres, OpenCV convention
    width: int
    height: int
    ground_height: float = 0.0  # metres, world z of the ground plane
    source: str = "default (the dataset's view 0)"

    def cameras(self) -> Cameras:
        """As a batch of one: K [1, 3, 3], world_to_cam [1, 4, 4]."""
        return Cameras(
            self.K[None].float(), self.world_to_cam[None].float(), self.width, self.height
        )

    def resized(self, width: int, height: int) -> CameraSpec:
        """The same camera for images of another size (K scaled per axis)."""
        scale = torch.tensor([width / self.width, height / self.height, 1.0], dtype=self.K.dtype)
        return CameraSpec(
            self.K * scale[:, None],
            self.world_to_cam,
            width,
            height,
            self.ground_height,
            self.source,
        )

    def cropped(self, left: int, top: int, width: int, height: int) -> CameraSpec:
        """The same camera for the image window [top, top+height) × [left, left+width) in pixels
        (the principal point moves by the window's corner)."""
        K = self.K.clone()
        K[0, 2] -= left
        K[1, 2] -= top
        return CameraSpec(K, self.world_to_cam, width, height, self.ground_height, self.source)

    def to_json(self) -> dict:
        return {
            "K": self.K.double().tolist(),
            "world_to_cam": self.world_to_cam.double().tolist(),
            "width": self.width,
            "height": self.height,
            "ground_height": self.ground_height,
        }


def default_camera(width: int, height: int, view: int = 0) -> CameraSpec:
    """The dataset's view ``view`` at ``width × height`` (docs/design.md#conventions)."""
    from ..render.cameras import dataset_view

    camera = dataset_view(width, height, view)
    return CameraSpec(camera.K[0], camera.world_to_cam[0], width, height)


def _matrix(data: dict, key: str, shape: tuple[int, int], source: str) -> Tensor:
    if key not in data:
        raise InputError("missing", source=source, field=key)
    try:
        value = torch.tensor(data[key], dtype=torch.float64)
    except (TypeError, ValueError):
        raise InputError(f"expected a {shape[0]}×{shape[1]} list of numbers", source, key) from None
    if tuple(value.shape) != shape:
        raise InputError(f"expected shape {list(shape)}, got {list(value.shape)}", source, key)
    if not bool(torch.isfinite(value).all()):
        raise InputError("non-finite values", source=source, field=key)
    return value


def read_camera(path: str | os.PathLike, width: int, height: int) -> CameraSpec:
    """The camera file at ``path`` for frames of ``width × height`` pixels (see module doc)."""
    source = str(path)
    data = read_json(path, expected="a JSON object with K and world_to_cam")
    K, size = _intrinsics(data, source, width, height)
    world_to_cam = _matrix(data, "world_to_cam", (4, 4), source)
    rotation = world_to_cam[:3, :3]
    if not torch.allclose(rotation @ rotation.T, torch.eye(3, dtype=torch.float64), atol=1e-3):
        raise InputError("its 3×3 block is not a rotation", source=source, field="world_to_cam")
    if abs(float(torch.det(rotation)) - 1) > 1e-3 or not torch.allclose(
        world_to_cam[3], torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=torch.float64)
    ):
        raise InputError(
            "expected a rigid transform (det +1, last row 0 0 0 1)", source, "world_to_cam"
        )
    ground = data.get("ground_height", 0.0)
    if not isinstance(ground, (int, float)) or not math.isfinite(ground):
        raise InputError(f"expected a number in metres, got {ground!r}", source, "ground_height")
    spec = CameraSpec(K, world_to_cam, size[0], size[1], float(ground), source)
    return spec.resized(width, height) if tuple(size) != (width, height) else spec


def read_intrinsics(path: str | os.PathLike, width: int, height: int) -> Tensor | None:
    """K [3, 3] at ``width × height`` pixels of a camera file that has no ``world_to_cam`` (its
    intrinsics alone, e.g. from a checkerboard calibration: the pose and the ground are then
    read from the video), or None for a file with a pose (:func:`read_camera` reads it)."""
    source = str(path)
    data = read_json(path, expected="a JSON object with K and world_to_cam")
    if "world_to_cam" in data:
        return None
    K, size = _intrinsics(data, source, width, height)
    return K * torch.tensor([width / size[0], height / size[1], 1.0], dtype=K.dtype)[:, None]


# A camera file's width:height may differ from the video's by an encoder's padding (1080 →
# 1088 rows: 0.7 %), not by a turn (a phone's clip that lost its rotation: 16:9 → 9:16) or a
# crop to another shape (16:9 → 4:3, 29 %), which scaling K per axis would take for a lens
MAX_ASPECT_CHANGE = 0.05


def _intrinsics(data: dict, source: str, width: int, height: int) -> tuple[Tensor, list[int]]:
    """A camera file's K [3, 3] and the [width, height] it was made for (the frames' when not
    given), checked: its shape within MAX_ASPECT_CHANGE of the frames'."""
    K = _matrix(data, "K", (3, 3), source)
    if not (K[0, 0] > 0 and K[1, 1] > 0 and K[2, 2] == 1 and K[2, :2].abs().sum() == 0):
        raise InputError(
            "expected [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0", source, "K"
        )
    size = []
    for key, default in (("width", width), ("height", height)):
        value = data.get(key, default)
        if not isinstance(value, int) or value < 1:
            raise InputError(f"expected a positive integer, got {value!r}", source, key)
        size.append(value)
    if abs(math.log(size[0] * height / (size[1] * width))) > MAX_ASPECT_CHANGE:
        raise InputError(
            f"K was made for {size[0]}×{size[1]} frames and the video's are {width}×{height}, "
            "another shape: a camera of the other orientation (a landscape calibration for a "
            "portrait clip), a video on its side (a phone's clip that lost its rotation: turn it "
            "upright first) or cropped; give the camera of these frames",
            source,
            "width",
        )
    cx, cy = float(K[0, 2]), float(K[1, 2])
    if not (0 < cx < size[0] and 0 < cy < size[1]):
        raise InputError(
            f"its principal point ({cx:g}, {cy:g}) is outside the {size[0]}×{size[1]} image: "
            "K was made for another image size; give that size as width and height",
            source,
            "K",
        )
    return K, size


def write_camera(path: str | os.PathLike, camera: CameraSpec) -> None:
    with atomic_file(path) as tmp:
        tmp.write_text(json.dumps(camera.to_json(), indent=1) + "\n")
