"""The hand that lets a drop go (render/hand.py): its shape, and how it covers the object."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import torch

from reconphys.render import Cameras, intrinsics_from_fov, look_at
from reconphys.render.hand import (
    arm_direction,
    composite_hand,
    draw_hand,
    hand_gaussians,
    object_grip,
)
from reconphys.render.scene import draw_look

TOP = np.array([0.0, 0.0, 0.5])


def _camera(size: int = 48) -> Cameras:  # 1.2 m from the object's top, a little above it
    eye = torch.tensor([[-1.2, 0.0, 0.7]], dtype=torch.float64)
    target = torch.tensor(TOP[None], dtype=torch.float64)
    K = intrinsics_from_fov(40.0, size, size, dtype=torch.float64)[None]
    return Cameras(K, look_at(eye, target), size, size)


def test_a_hand_grips_the_top_and_its_forearm_points_away_from_the_camera():
    """Every Gaussian is at most a few cm below the object's top, in the drawn skin tone
    (± the jitter); the forearm ends 0.45–0.5 m up the arm; drawn forearms point away from the
    camera (within ±69°) and upwards (29–63°); the grip is the object's top and its half-width
    there."""
    rng = np.random.default_rng(0)
    eye = np.array([-1.2, 0.0, 0.7])
    for _ in range(20):
        spec = draw_hand(rng)
        arm = arm_direction(spec, TOP, eye)
        hand = hand_gaussians(TOP, 0.04, arm, spec)
        means = hand.means.numpy()
        assert abs(np.linalg.norm(arm) - 1) < 1e-12
        assert means[:, 2].min() > TOP[2] - 0.04
        assert 0.42 < float(((means - TOP) @ arm).max()) < 0.56
        assert np.abs(hand.colors.numpy() - np.array(spec.skin)).max() < 0.1
        away = (TOP - eye)[:2] / np.linalg.norm((TOP - eye)[:2])
        assert arm[:2] @ away / np.linalg.norm(arm[:2]) > np.cos(np.radians(70))
        assert np.radians(28) < np.arcsin(arm[2]) < np.radians(64)
    anchors = np.array([[0.0, 0.0, 0.0], [0.05, 0.0, 0.48], [0.0, 0.0, 0.5], [0.3, 0.0, 0.2]])
    top, half_width = object_grip(anchors)
    assert np.array_equal(top, anchors[2]) and abs(half_width - 0.05) < 1e-12


def test_the_hand_hides_the_object_only_where_it_is_nearer():
    """Over an object's mask the hand is drawn (and the mask loses those pixels) when the
    object's centre is behind it, and not at all when the object is in front; away from its
    footprint the frames are as they were; held still until the release, then moving."""
    cameras = _camera()
    spec = replace(draw_hand(np.random.default_rng(1)), grip="front", speed=0.5)
    arm = arm_direction(spec, TOP, np.array([-1.2, 0.0, 0.7]))
    hand = hand_gaussians(TOP, 0.04, arm, spec)
    frames = torch.full((1, 4, 48, 48, 3), 0.3, dtype=torch.float64)
    masks = torch.zeros(1, 4, 48, 48, dtype=torch.bool)
    masks[:, :, 20:40, 14:34] = True  # the object, under and around the hand's fingers
    release = torch.tensor([-0.06, 0.0, 0.1, 0.3], dtype=torch.float64)
    look = draw_look(np.random.default_rng(0), (0.0, 0.0))
    velocity = arm * spec.speed
    far = torch.full((1, 4), 5.0, dtype=torch.float64)  # the object behind everything
    near = torch.full((1, 4), 0.1, dtype=torch.float64)  # the object in front of everything
    shown, visible = composite_hand(frames, masks, far, hand, velocity, release, cameras, look)
    hidden = masks & ~visible
    assert hidden[0, 0].sum() > 10 and torch.equal(visible[0, 0], visible[0, 1])  # held still
    assert not torch.equal(visible[0, 1], visible[0, 3])  # then gone up the arm
    assert torch.equal(hidden, hidden & masks)  # a hand only takes pixels away
    drawn = (shown - frames).abs().amax(-1) > 1e-6  # [1, T, H, W]
    assert drawn[hidden].all()
    shown_near, visible_near = composite_hand(
        frames, masks, near, hand, velocity, release, cameras, look
    )
    assert torch.equal(visible_near, masks)
    assert torch.equal(shown_near[masks], frames[masks])
    assert torch.equal(shown_near[~masks], shown[~masks])  # off the object: the same hand
    untouched = ~drawn[0, 0]
    assert untouched.sum() > 0.5 * 48 * 48
    assert torch.equal(shown[0, 0][untouched], frames[0, 0][untouched])
