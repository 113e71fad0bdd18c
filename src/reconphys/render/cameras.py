"""Pinhole cameras in the OpenCV convention (docs/design.md#conventions).

Camera frame: x right, y down, z forward into the scene. ``K`` maps camera coordinates to pixels,
``world_to_cam`` maps world points (metres, z up) to camera coordinates. Pixel ``(u, v)`` covers
``[u, u + 1) × [v, v + 1)``, so its centre is at ``(u + 0.5, v + 0.5)`` and the image centre at
``(width / 2, height / 2)``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import torch
from torch import Tensor

from ..errors import InputError


@dataclass
class Cameras:
    """A set of C pinhole cameras sharing one image size, with optional leading batch dims."""

    K: Tensor  # [..., C, 3, 3] intrinsics in pixels
    world_to_cam: Tensor  # [..., C, 4, 4] rigid transform, metres
    width: int  # pixels
    height: int  # pixels

    def __post_init__(self) -> None:
        if self.K.shape[-2:] != (3, 3) or self.world_to_cam.shape[-2:] != (4, 4):
            raise ValueError(
                f"Cameras: expected K [..., C, 3, 3] and world_to_cam [..., C, 4, 4], "
                f"got {tuple(self.K.shape)} and {tuple(self.world_to_cam.shape)}"
            )
        if self.K.shape[:-2] != self.world_to_cam.shape[:-2]:
            raise ValueError(
                f"Cameras: K {tuple(self.K.shape)} and world_to_cam "
                f"{tuple(self.world_to_cam.shape)} must have the same leading dims [..., C]"
            )
        if self.width <= 0 or self.height <= 0:
            raise ValueError(
                f"Cameras: image size must be positive, got {self.width}×{self.height}"
            )

    def select(self, index: Tensor | Sequence[int] | slice) -> Cameras:
        """The cameras ``index`` (indices or a slice along C): ``[..., C', ·, ·]``."""
        if not isinstance(index, slice):
            index = torch.as_tensor(index, dtype=torch.int64, device=self.K.device)
        return Cameras(
            self.K[..., index, :, :], self.world_to_cam[..., index, :, :], self.width, self.height
        )

    @property
    def num_cameras(self) -> int:
        return self.K.shape[-3]

    @property
    def batch_shape(self) -> torch.Size:
        """Leading batch dims ``...`` (empty for an unbatched camera set)."""
        return self.K.shape[:-3]

    @property
    def cam_to_world(self) -> Tensor:  # [..., C, 4, 4]
        """Inverse of ``world_to_cam`` (exact for a rigid transform: ``[Rᵀ, −Rᵀt]``)."""
        rotation = self.world_to_cam[..., :3, :3]
        translation = self.world_to_cam[..., :3, 3:]
        inverse = torch.zeros_like(self.world_to_cam)
        inverse[..., :3, :3] = rotation.transpose(-1, -2)
        inverse[..., :3, 3:] = -rotation.transpose(-1, -2) @ translation
        inverse[..., 3, 3] = 1.0
        return inverse

    @property
    def centers(self) -> Tensor:  # [..., C, 3]
        """Camera centres in world coordinates, metres."""
        return self.cam_to_world[..., :3, 3]

    def to(self, *args, **kwargs) -> Cameras:
        """Move / cast the tensors, like ``Tensor.to``."""
        return Cameras(
            K=self.K.to(*args, **kwargs),
            world_to_cam=self.world_to_cam.to(*args, **kwargs),
            width=self.width,
            height=self.height,
        )

    def expand(self, batch_shape: Sequence[int]) -> Cameras:
        """Same cameras for every element of a batch: ``[C, ...]`` → ``[*batch_shape, C, ...]``."""
        batch_shape = tuple(batch_shape)
        return Cameras(
            K=self.K.expand(*batch_shape, *self.K.shape[-3:]),
            world_to_cam=self.world_to_cam.expand(*batch_shape, *self.world_to_cam.shape[-3:]),
            width=self.width,
            height=self.height,
        )


def intrinsics_from_fov(
    fov_deg: float,
    width: int,
    height: int,
    dtype: torch.dtype = torch.float32,
    device: torch.device | str | None = None,
) -> Tensor:  # [3, 3]
    """Pinhole intrinsics from the **vertical** field of view, in pixels.

    ``fov_deg`` is the full vertical opening angle in degrees (top to bottom edge of the image).
    Pixels are square (``fx = fy``) and the principal point is the image centre
    ``(width / 2, height / 2)``; the horizontal field of view follows from the aspect ratio.
    """
    if not 0.0 < fov_deg < 180.0:
        raise ValueError(f"fov_deg: expected a vertical field of view in (0, 180), got {fov_deg}")
    focal = 0.5 * height / math.tan(math.radians(fov_deg) / 2.0)
    return torch.tensor(
        [[focal, 0.0, width / 2.0], [0.0, focal, height / 2.0], [0.0, 0.0, 1.0]],
        dtype=dtype,
        device=device,
    )


def look_at(
    eye: Tensor,  # [..., 3] camera centre, world frame, metres
    target: Tensor,  # [..., 3] point to look at, world frame, metres
    up: Sequence[float] | Tensor = (0.0, 0.0, 1.0),  # [3] or [..., 3] world "up"
) -> Tensor:  # [..., 4, 4]
    """World-to-camera transform (OpenCV: x right, y down, z forward) looking from eye to target.

    The camera z axis points from ``eye`` to ``target``, x is ``z × up`` (to the right in the
    image) and y is ``z × x`` (down in the image, i.e. against ``up``). The result maps ``eye`` to
    the origin and ``target`` onto the +z axis at distance ``‖target − eye‖``.
    """
    up = torch.as_tensor(up, dtype=eye.dtype, device=eye.device).expand_as(eye)
    forward = target - eye
    distance = forward.norm(dim=-1, keepdim=True)
    if bool((distance <= 0).any()):
        raise ValueError("look_at: eye and target must differ")
    forward = forward / distance
    right = torch.linalg.cross(forward, up, dim=-1)
    right_norm = right.norm(dim=-1, keepdim=True)
    if bool((right_norm < 1e-8).any()):
        raise ValueError("look_at: the viewing direction must not be parallel to `up`")
    right = right / right_norm
    down = torch.linalg.cross(forward, right, dim=-1)

    rotation = torch.stack([right, down, forward], dim=-2)  # rows = camera axes in world coords
    world_to_cam = torch.zeros(*eye.shape[:-1], 4, 4, dtype=eye.dtype, device=eye.device)
    world_to_cam[..., :3, :3] = rotation
    world_to_cam[..., :3, 3] = -(rotation @ eye.unsqueeze(-1)).squeeze(-1)
    world_to_cam[..., 3, 3] = 1.0
    return world_to_cam


def dataset_views(
    width: int,
    height: int,
    radius: float = 2.0,
    fov_deg: float = 40.0,
    elevation_deg: float = 15.0,
    target: Sequence[float] = (0.0, 0.0, 0.3),
    azimuths_deg: Sequence[float] = (0.0, 90.0, 180.0, 270.0),
    dtype: torch.dtype = torch.float32,
    device: torch.device | str | None = None,
) -> Cameras:
    """The dataset's fixed views (docs/design.md#conventions): cameras on a circle around ``target``
    looking at it.

    Camera ``i`` sits at distance ``radius`` (metres) from ``target``, at azimuth
    ``azimuths_deg[i]`` about the world z axis (0° = on the +x side of the target, 90° = +y side)
    and ``elevation_deg`` above the horizontal: horizontal distance ``radius·cos(el)``, height
    ``target_z + radius·sin(el)``. ``fov_deg`` is the vertical field of view. Returns C =
    ``len(azimuths_deg)`` cameras without batch dims.
    """
    azimuths = torch.tensor([math.radians(a) for a in azimuths_deg], dtype=torch.float64)
    elevation = math.radians(elevation_deg)
    target_t = torch.tensor(target, dtype=torch.float64)
    offsets = torch.stack(
        [
            radius * math.cos(elevation) * torch.cos(azimuths),
            radius * math.cos(elevation) * torch.sin(azimuths),
            torch.full_like(azimuths, radius * math.sin(elevation)),
        ],
        dim=-1,
    )  # [C, 3]
    eyes = target_t + offsets
    world_to_cam = look_at(eyes, target_t.expand_as(eyes))
    K = intrinsics_from_fov(fov_deg, width, height, dtype=torch.float64)
    K = K.expand(len(azimuths_deg), 3, 3)
    return Cameras(
        K=K.to(dtype=dtype, device=device).contiguous(),
        world_to_cam=world_to_cam.to(dtype=dtype, device=device).contiguous(),
        width=width,
        height=height,
    )


def dataset_view(width: int, height: int, view: int = 0) -> Cameras:
    """Dataset view ``view`` (0–3: azimuth 0°, 90°, 180°, 270°) as a single camera (C = 1)."""
    if not 0 <= view < 4:
        raise InputError(f"expected 0, 1, 2 or 3, got {view}", field="--view")
    cameras = dataset_views(width, height)
    return Cameras(cameras.K[view : view + 1], cameras.world_to_cam[view : view + 1], width, height)
