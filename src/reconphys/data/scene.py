"""The ``realistic`` look of a sample (docs/design.md#synthetic-dataset): what is drawn for it and
the cameras framed on its motion.

A realistic sample draws, from its own random stream (so the physics of a seed is the same in
both looks), the object's size, a scene (render/scene.py: ground, backdrop, light, noise), a
camera (vertical field of view, elevation, azimuth, how much of the image the motion spans and
where it sits), the video's compression quality and, where asked, the shutter's open time and
the rows' readout time. The four views share intrinsics and distance and sit 90° apart around
the centre of the motion, as in the plain look.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace

import numpy as np
import torch

from ..assets.gaussians import SH_C0
from ..render import Cameras, intrinsics_from_fov, look_at
from ..render.hand import HandSpec, draw_hand
from ..render.scene import (
    SceneLook,
    contrast_look,
    draw_look,
    grey_colours,
    grey_look,
    print_pattern,
    vivid_look,
)
from .objects import CanonicalObject
from .sampling import sample_seed
from .settings import DataSettings

MIN_CAMERA_HEIGHT = 0.05  # metres above the ground
SCENE_STREAM = 1  # the realistic look's random stream, beside the sample's own (0)
VIVID_STREAM = 2  # whether and how a scene is vivid (settings.vivid_share): a stream of its own
CONTRAST_STREAM = 3  # whether and how its floor is high-contrast (settings.contrast_share)
HAND_STREAM = 4  # whether and how a hand lets the object go (settings.hand_share)
EXPOSURE_STREAM = 5  # how long the shutter stays open (settings.exposure_range_s)
READOUT_STREAM = 6  # how long the rows take to read (settings.readout_range_s)
GREY_STREAM = 7  # whether and how grey the object is (settings.grey_share)


@dataclass(frozen=True)
class SceneSpec:
    """The random part of a realistic sample's look."""

    size: float  # the object's largest side, metres
    look: SceneLook
    fov_deg: float  # vertical
    elevation_deg: float
    azimuth_deg: float  # of view 0; the others follow at +90°, +180°, +270°
    framing: float  # share of the image height the motion's bounding sphere spans
    offset: tuple[float, float]  # where the motion sits, in units of the free margin, [-1, 1]
    video_quality: float  # H.264 quality 0–10
    noise_seed: int
    hand: HandSpec | None = None  # a hand holding the object at frame 0 (render/hand.py)
    exposure_s: float = 0.0  # the shutter open this long about each frame's time (0: sharp)
    readout_s: float = 0.0  # the rows read top to bottom over this long (0: all at once)

    def to_dict(self) -> dict:  # JSON-ready, without the noise seed (nor a hand when none, nor
        # a sharp shutter: the looks stored before the shutter existed read the same)
        skipped = ("noise_seed", "hand", "exposure_s", "readout_s")
        out = {k: v for k, v in asdict(self).items() if k not in skipped}
        for name in ("exposure_s", "readout_s"):
            if getattr(self, name):
                out[name] = getattr(self, name)
        return out if self.hand is None else {**out, "hand": self.hand.to_dict()}


def _drawn_seconds(seed, stream: int, bounds: tuple[float, float]) -> float:
    """Uniform over ``bounds`` (seconds) from the sample's ``stream``; 0 when ``bounds`` is (0, 0),
    that stream never drawn."""
    if not max(bounds) > 0:
        return 0.0
    return float(np.random.default_rng([seed, stream]).uniform(*bounds))


def draw_scene(settings: DataSettings, object_id: str, sample_index: int) -> SceneSpec:
    """The look of sample ``sample_index`` of ``object_id`` (a stream apart from its physics)."""
    seed = sample_seed(settings.seed, object_id, sample_index)
    rng = np.random.default_rng([seed, SCENE_STREAM])
    size = float(rng.uniform(*settings.object_size_range))
    look = draw_look(rng, settings.noise_range)
    if settings.vivid_share > 0:
        vivid = np.random.default_rng([seed, VIVID_STREAM])
        if vivid.random() < settings.vivid_share:
            look = vivid_look(vivid, look, size)
    if settings.contrast_share > 0:
        contrast = np.random.default_rng([seed, CONTRAST_STREAM])
        if contrast.random() < settings.contrast_share:
            look = contrast_look(contrast, look)
    if settings.grey_share > 0:
        grey = np.random.default_rng([seed, GREY_STREAM])
        if grey.random() < settings.grey_share:
            look = grey_look(grey, look)
    hand = None
    if settings.hand_share > 0:
        held = np.random.default_rng([seed, HAND_STREAM])
        if held.random() < settings.hand_share:
            hand = draw_hand(held)
    exposure = _drawn_seconds(seed, EXPOSURE_STREAM, settings.exposure_range_s)
    readout = _drawn_seconds(seed, READOUT_STREAM, settings.readout_range_s)
    return SceneSpec(
        size=size,
        look=look,
        fov_deg=float(rng.uniform(*settings.fov_range_deg)),
        elevation_deg=float(rng.uniform(*settings.elevation_range_deg)),
        azimuth_deg=float(rng.uniform(0.0, 360.0)),
        framing=float(rng.uniform(*settings.framing_range)),
        offset=(float(rng.uniform(-1, 1)), float(rng.uniform(-1, 1))),
        video_quality=float(rng.uniform(*settings.video_quality_range)),
        noise_seed=int(rng.integers(0, 2**31 - 1)),
        hand=hand,
        exposure_s=exposure,
        readout_s=readout,
    )


def look_from_dict(data: dict) -> SceneLook:
    """A sample's stored look (``meta["scene"]["look"]``) → SceneLook (lists back to tuples)."""

    def tuples(value):
        return tuple(tuples(v) for v in value) if isinstance(value, list) else value

    return SceneLook(**{k: tuples(v) for k, v in data.items()})


def printed_object(obj: CanonicalObject, look: SceneLook) -> CanonicalObject:
    """``obj`` with ``look``'s pattern printed on its Gaussians (the vivid look) and its colours
    made grey (the grey look); else as it is: the sample's asset carries the colours its video
    shows."""
    unchanged = look.object_saturation == 1.0 and look.object_lightness is None
    if look.object_pattern == "none" and unchanged:
        return obj
    g = obj.gaussians
    generator = torch.Generator().manual_seed(look.texture_seed + 1)
    colours = print_pattern(g.colors.double(), g.means.double(), look, generator)
    colours = grey_colours(colours, look)
    return replace(obj, gaussians=replace(g, sh0=((colours - 0.5) / SH_C0).to(g.sh0.dtype)))


def framed_cameras(
    points: np.ndarray,  # [T, P, 3] every anchor of every frame, metres
    spec: SceneSpec,
    resolution: int,
) -> Cameras:
    """Four views whose images hold the whole motion: its bounding sphere spans ``framing`` of the
    image height, shifted off-centre by ``offset`` of the margin left (never out of view)."""
    flat = points.reshape(-1, 3).astype(np.float64)
    centre = 0.5 * (flat.min(0) + flat.max(0))
    radius = float(np.linalg.norm(flat - centre, axis=1).max())
    half_fov = math.radians(spec.fov_deg) / 2
    half_angle = spec.framing * half_fov  # the sphere's angular radius
    distance = radius / math.sin(half_angle)
    margin = 0.9 * (half_fov - half_angle)  # angle the sphere may move off the image centre
    elevation = math.radians(spec.elevation_deg)
    lowest = math.asin(min(1.0, max(0.0, (MIN_CAMERA_HEIGHT - centre[2]) / distance)))
    elevation = max(elevation, lowest)
    eyes, targets = [], []
    for k in range(4):
        azimuth = math.radians(spec.azimuth_deg + 90.0 * k)
        back = np.array(
            [
                math.cos(elevation) * math.cos(azimuth),
                math.cos(elevation) * math.sin(azimuth),
                math.sin(elevation),
            ]
        )  # from the centre towards the camera
        eye = centre + distance * back
        right = np.cross(-back, [0.0, 0.0, 1.0])
        right /= np.linalg.norm(right)
        up = np.cross(right, -back)
        # aim beside the centre, so that it appears offset by the given angles
        shift = math.tan(margin) * distance
        target = centre - shift * (spec.offset[0] * right + spec.offset[1] * up)
        eyes.append(eye)
        targets.append(target)
    world_to_cam = look_at(torch.tensor(np.array(eyes)), torch.tensor(np.array(targets)))
    K = intrinsics_from_fov(spec.fov_deg, resolution, resolution, dtype=torch.float64)
    return Cameras(
        K=K.expand(4, 3, 3).float().contiguous(),
        world_to_cam=world_to_cam.float().contiguous(),
        width=resolution,
        height=resolution,
    )
