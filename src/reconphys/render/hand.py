"""A hand that lets the object go: 3D Gaussians of a palm, four fingers, a thumb and a forearm.

Every clip of the realistic look shows the object alone; a real drop starts in a hand, which
opens and withdraws (or stays) after the release. :func:`hand_gaussians` builds one gripping the
object's top from above; :func:`composite_hand` renders it moving into frames already made, where
it hides the object wherever it is nearer than the object's centre. Used by ``make-data
--hand-share`` (data/scene.py draws a :class:`HandSpec` per sample) and by
``benchmarks/hand_release.py``. No shadow of the hand is drawn.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np
import torch
from torch import Tensor

from ..assets.gaussians import Gaussians
from ..geometry import axis_angle_to_matrix, matrix_to_quaternion
from . import render
from .cameras import Cameras
from .scene import SceneLook, shade_gaussians

# Skin tones (linear RGB in [0, 1]) from light to dark; a hand's is one of them, ±10 % brighter.
SKIN_TONES = ((0.95, 0.80, 0.69), (0.87, 0.67, 0.53), (0.70, 0.49, 0.36), (0.45, 0.30, 0.21))
GRIPS = ("front", "behind")


@dataclass(frozen=True)
class HandSpec:
    """How a sample's hand holds and leaves the object (the random part: data/scene.py)."""

    grip: str  # "front": the fingers over the object's side that faces the camera; "behind"
    azimuth_deg: float  # of the forearm, from "straight away from view 0's camera"
    elevation_deg: float  # of the forearm above the horizontal
    skin: tuple[float, float, float]  # RGB in [0, 1]
    speed: float  # m/s along the forearm after the release (0: the hand stays)
    seed: int  # the Gaussians' colour jitter

    def to_dict(self) -> dict:  # JSON-ready
        return {k: list(v) if isinstance(v, tuple) else v for k, v in asdict(self).items()}


def draw_hand(rng: np.random.Generator) -> HandSpec:
    """A hand: the forearm within ±69° of straight away from the camera, 29–63° up, a quarter of
    the hands kept still after the release, the others withdrawn at 0.2–1 m/s."""
    grip = GRIPS[int(rng.integers(len(GRIPS)))]
    azimuth = float(np.degrees(rng.uniform(-1.2, 1.2)))
    elevation = float(np.degrees(rng.uniform(0.5, 1.1)))
    tone = np.clip(
        np.array(SKIN_TONES[int(rng.integers(len(SKIN_TONES)))]) * rng.uniform(0.9, 1.1), 0, 1
    )
    speed = 0.0 if rng.uniform() < 0.25 else float(rng.uniform(0.2, 1.0))
    return HandSpec(grip, azimuth, elevation, tuple(float(x) for x in tone), speed,
                    int(rng.integers(0, 2**31 - 1)))  # fmt: skip


def _limb(start: np.ndarray, end: np.ndarray, radius: float, spacing: float) -> list:
    """(centre, standard deviations along x, y, z, the z axis's direction) along a limb."""
    length = float(np.linalg.norm(end - start))
    count = max(2, math.ceil(length / spacing) + 1)
    direction = (end - start) / max(length, 1e-9)
    along = max(spacing * 0.7, radius * 0.6)
    return [(start + (end - start) * s, (radius, radius, along), direction)
            for s in np.linspace(0, 1, count)]  # fmt: skip


def _z_to(directions: np.ndarray) -> Tensor:  # [N, 3] unit → [N, 4] (w, x, y, z)
    """The rotations that take the z axis to each of ``directions`` (geometry.py's)."""
    d = torch.as_tensor(directions, dtype=torch.float64)
    cross = torch.linalg.cross(torch.tensor([0.0, 0.0, 1.0], dtype=d.dtype).expand_as(d), d)
    sin = cross.norm(dim=-1, keepdim=True)
    x_axis = torch.tensor([1.0, 0.0, 0.0], dtype=d.dtype)  # for −z: a half turn about x
    axis = torch.where(sin > 1e-9, cross / sin.clamp_min(1e-12), x_axis)
    return matrix_to_quaternion(axis_angle_to_matrix(axis * torch.atan2(sin, d[:, 2:])))


def arm_direction(spec: HandSpec, top: np.ndarray, eye: np.ndarray) -> np.ndarray:
    """[3] unit vector up the forearm: ``spec``'s angles from straight away from ``eye``."""
    away = top[:2] - eye[:2]
    azimuth = math.atan2(away[1], away[0]) + math.radians(spec.azimuth_deg)
    up = math.radians(spec.elevation_deg)
    return np.array([math.cos(azimuth) * math.cos(up), math.sin(azimuth) * math.cos(up),
                     math.sin(up)])  # fmt: skip


def hand_gaussians(
    top: np.ndarray,  # [3] the object's highest point at the release, world metres
    half_width: float,  # the object's horizontal half-extent near its top, metres
    arm: np.ndarray,  # [3] unit, from the hand up the forearm
    spec: HandSpec,
) -> Gaussians:
    """About 60 Gaussians [N, ·] (float64): a palm on the object's top, four fingers and a thumb
    curling down over it (``spec.grip``), a 0.4 m forearm along ``arm``, in ``spec.skin``."""
    side = np.cross(arm, [0.0, 0.0, 1.0])
    side = side / max(np.linalg.norm(side), 1e-9)
    back = np.array([arm[0], arm[1], 0.0])
    back = back / max(np.linalg.norm(back), 1e-9)  # horizontal, away from the camera
    reach = min(max(half_width, 0.02), 0.06)
    fingers = -1.0 if spec.grip == "front" else 1.0  # −back: towards the camera
    palm = (
        top + np.array([0.0, 0.0, 0.025]) + (0.0 if spec.grip == "front" else reach + 0.02) * back
    )
    parts = [(palm, (0.045, 0.04, 0.014), np.array([0.0, 0.0, 1.0]))]
    down = np.array([0.0, 0.0, 1.0])
    for offset in (-1.5, -0.5, 0.5, 1.5):
        root = palm + fingers * back * 0.035 + side * offset * 0.018
        tip = top + fingers * back * reach + side * offset * 0.018 - 0.02 * down
        parts += _limb(root, tip, 0.009, 0.012)
    thumb = -fingers if spec.grip == "front" else 1.0
    root = palm + thumb * back * 0.03 + side * 0.03 * (spec.grip != "front")
    parts += _limb(root, top + thumb * back * reach - 0.015 * down, 0.011, 0.012)
    wrist = palm + arm * 0.05
    parts += _limb(wrist, wrist + arm * 0.4, 0.035, 0.03)
    rng = np.random.default_rng(spec.seed)
    colours = np.clip(np.array(spec.skin) + rng.normal(0, 0.02, (len(parts), 3)), 0, 1)
    return Gaussians.from_activated(
        torch.tensor(np.array([p[0] for p in parts])),
        torch.tensor(np.array([p[1] for p in parts])),
        torch.full((len(parts),), 0.99, dtype=torch.float64),
        torch.tensor(colours),
        _z_to(np.array([p[2] for p in parts])),
    )


def object_grip(anchors: np.ndarray) -> tuple[np.ndarray, float]:
    """Where a hand holds an object whose anchors [N, 3] are at the release: its highest point
    and its horizontal half-extent within 3 cm below it."""
    top = anchors[anchors[:, 2].argmax()]
    near = anchors[anchors[:, 2] > top[2] - 0.03]
    return top, float(np.linalg.norm(near[:, :2] - top[:2], axis=1).max())


def composite_hand(
    frames: Tensor,  # [C, T, H, W, 3] in [0, 1], the object in its scene
    masks: Tensor,  # [C, T, H, W] bool, the object's
    object_depth: Tensor,  # [C, T] camera-space z of the object's centre, metres
    hand: Gaussians,  # at the release
    velocity: np.ndarray,  # [3] m/s, the hand's after the release
    release: Tensor,  # [T] seconds since the release of each frame (≤ 0: still held)
    cameras: Cameras,  # C cameras
    look: SceneLook,
) -> tuple[Tensor, Tensor]:  # frames [C, T, H, W, 3], the object's visible masks [C, T, H, W]
    """The hand over the frames, moving by ``velocity`` after the release; it hides the object
    where it is nearer than the object's centre, which is then no longer in the object's mask."""
    out_frames, out_masks = [], []
    shift = torch.as_tensor(velocity, dtype=hand.means.dtype)
    for t in range(frames.shape[1]):
        moved = hand.with_means(hand.means + shift * max(float(release[t]), 0.0))
        shown = render(shade_gaussians(moved, look), cameras, backend="torch")
        alpha = shown.alpha.to(frames.dtype)  # [C, H, W]
        behind = masks[:, t] & (shown.depth > object_depth[:, t, None, None])
        alpha = torch.where(behind, torch.zeros_like(alpha), alpha)
        rgb = torch.where(
            behind[..., None], torch.zeros_like(alpha[..., None]), shown.rgb.to(frames.dtype)
        )
        out_frames.append(rgb + (1 - alpha[..., None]) * frames[:, t])
        out_masks.append(masks[:, t] & ~(alpha > 0.5))
    return torch.stack(out_frames, 1).clamp(0, 1), torch.stack(out_masks, 1)
