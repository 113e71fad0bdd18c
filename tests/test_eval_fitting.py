"""Geometry of the per-scene fits (no dataset needed): triangulation, visual hull, plot ticks."""

from __future__ import annotations

import itertools
import math

import pytest
import torch

from reconphys.assets.gaussians import Gaussians
from reconphys.eval.methods.fitting import (
    look_at_point,
    project,
    silhouette_centre,
    triangulate,
    visual_hull,
)
from reconphys.eval.plots import nice_ticks
from reconphys.geometry import axis_angle_to_matrix
from reconphys.render import dataset_views, render


def test_look_at_point_is_the_dataset_target():
    cameras = dataset_views(32, 32, target=(0.1, -0.2, 0.3))
    assert torch.allclose(look_at_point(cameras), torch.tensor([0.1, -0.2, 0.3]), atol=1e-5)


def test_triangulate_recovers_a_projected_point():
    cameras = dataset_views(48, 48)
    point = torch.tensor([[0.05, -0.08, 0.42]])
    pixels, depth = project(point, cameras)
    assert (depth > 0).all()
    assert torch.allclose(triangulate(pixels[:, 0], cameras), point[0], atol=1e-4)


def _ball_image(centre, cameras):
    g = torch.Generator().manual_seed(0)
    direction = torch.randn(600, 3, generator=g)
    points = direction / direction.norm(dim=1, keepdim=True) * 0.12 * torch.rand(600, 1) ** (1 / 3)
    gaussians = Gaussians.from_activated(
        means=points + torch.tensor(centre),
        scales=torch.full((600, 3), 0.02),
        opacities=torch.full((600,), 0.9),
        colors=torch.full((600, 3), 0.8),
    )
    with torch.no_grad():
        return render(gaussians, cameras).rgb


def test_silhouette_centre_and_visual_hull_of_a_ball():
    cameras = dataset_views(32, 32)
    centre = (0.1, 0.05, 0.35)
    images = _ball_image(centre, cameras)
    found = silhouette_centre(images, cameras)
    assert torch.allclose(found, torch.tensor(centre), atol=0.03)  # < one pixel (≈ 0.045 m)
    hull, voxel = visual_hull(images, cameras)
    assert 0 < voxel < 0.05
    # Four horizontal views carve a square prism around the visible disc (radius ≈ 0.12 m plus
    # the Gaussians' 3σ tails): the hull reaches √2 times further at its corners, no more.
    radius = (hull - torch.tensor(centre)).norm(dim=1)
    assert radius.max() < math.sqrt(2) * (0.12 + 3 * 0.02) + 2 * voxel
    inner = torch.tensor(centre) + 0.1 * torch.eye(3)  # points inside the ball
    assert torch.cdist(inner, hull).min(1).values.max() < voxel  # ...lie in the hull


def test_rotations_match_rodrigues_and_are_smooth_at_zero():
    vectors = torch.tensor([[0.0, 0.0, 0.0], [0.0, 0.0, math.pi / 2]], requires_grad=True)
    rotations = axis_angle_to_matrix(vectors)
    assert torch.allclose(rotations[0], torch.eye(3), atol=1e-6)
    expected = torch.tensor([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    assert torch.allclose(rotations[1], expected, atol=1e-6)
    rotations.sum().backward()
    assert torch.isfinite(vectors.grad).all()


@pytest.mark.parametrize(
    ("low", "high"), [(0.0, 29.0), (10.3, 58.9), (-1.2, 0.4), (0.0001, 0.0009)]
)
def test_nice_ticks_cover_the_range_with_round_steps(low, high):
    ticks = nice_ticks(low, high)
    assert 2 <= len(ticks) <= 11
    assert all(low - 1e-12 <= t <= high + 1e-12 for t in ticks)
    steps = {round(b - a, 12) for a, b in itertools.pairwise(ticks)}
    assert len(steps) == 1
