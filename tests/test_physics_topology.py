"""Anchors, springs and binding against brute force."""

from __future__ import annotations

import pytest
import torch
from helpers import ball_points

from reconphys.physics import (
    compute_binding,
    deform_means,
    knn_springs,
    sample_volume_anchors,
    seed_from_id,
)


def sphere_shell(count: int, radius: float) -> torch.Tensor:
    p = ball_points(count, 1.0, seed=5)
    return radius * p / p.norm(dim=1, keepdim=True)


def test_anchors_fill_the_volume_of_a_surface_only_object():
    anchors = sample_volume_anchors(sphere_shell(6000, 0.25), 512, seed="shell")
    r = anchors.double().norm(dim=1)
    assert r.max() < 0.25 + 0.25 * 2 / 40 * 2, "anchors stay within a voxel of the surface"
    inner = (r < 0.125).double().mean().item()  # uniform in volume: (1/2)^3 = 12.5 %
    assert 0.07 < inner < 0.18


def test_anchors_are_seeded_by_object_id():
    points = ball_points(3000, 0.2)
    a = sample_volume_anchors(points, 256, seed="chair-01")
    assert torch.equal(a, sample_volume_anchors(points, 256, seed="chair-01"))
    assert not torch.equal(a, sample_volume_anchors(points, 256, seed="chair-02"))
    assert seed_from_id("chair-01") == seed_from_id("chair-01") != seed_from_id("chair-02")


def test_anchors_are_evenly_spread():
    anchors = sample_volume_anchors(ball_points(5000, 0.2), 256, seed="spread").double()
    distance = torch.cdist(anchors, anchors) + torch.eye(256, dtype=torch.float64) * 1e9
    nearest = distance.min(1).values
    assert nearest.min() > 0.3 * nearest.median(), "farthest-point sampling avoids clumps"


@pytest.mark.parametrize("num_points, count", [(3000, 256), (257, 257)])
def test_compiled_farthest_point_sampling_matches_the_reference(num_points, count):
    from reconphys._optional import numba_available
    from reconphys.physics.anchors import farthest_point_sampling, farthest_point_sampling_reference

    if not numba_available():
        pytest.skip("numba not installed: only the reference runs")
    points = torch.rand(num_points, 3, generator=torch.Generator().manual_seed(3)).double()
    points[7] = points[11]  # a duplicate: ties must resolve to the same (first) index
    fast = farthest_point_sampling(points, count, first=4)
    reference = farthest_point_sampling_reference(points, count, first=4)
    assert torch.equal(fast, reference)


def test_knn_springs_match_brute_force():
    points = torch.rand(60, 3, generator=torch.Generator().manual_seed(2), dtype=torch.float64)
    springs, rest = knn_springs(points, 5)
    pairs = {tuple(p) for p in springs.tolist()}
    assert len(pairs) == len(springs) and all(i < j for i, j in pairs)
    distance = torch.cdist(points, points) + torch.eye(60, dtype=torch.float64) * 1e9
    expected = set()
    for i, row in enumerate(distance.argsort(1)[:, :5].tolist()):
        expected |= {(min(i, j), max(i, j)) for j in row}
    assert pairs == expected
    lengths = (points[springs[:, 1]] - points[springs[:, 0]]).norm(dim=1)
    assert torch.allclose(rest.double(), lengths, rtol=1e-6)


def test_binding_weights_follow_inverse_distance():
    g = torch.Generator().manual_seed(4)
    anchors, means = torch.rand(40, 3, generator=g), torch.rand(25, 3, generator=g)
    index, weight = compute_binding(means, anchors, num_neighbors=6, power=2.0)
    assert torch.allclose(weight.sum(1), torch.ones(25))
    n = 3
    distance = (anchors - means[n]).norm(dim=1).double()
    nearest = distance.argsort()[:6]
    assert set(index[n].tolist()) == set(nearest.tolist())
    expected = distance[index[n]] ** -2
    assert torch.allclose(weight[n].double(), expected / expected.sum(), rtol=1e-5)


def test_binding_moves_means_with_a_translation():
    g = torch.Generator().manual_seed(4)
    anchors, means = torch.rand(40, 3, generator=g), torch.rand(25, 3, generator=g)
    index, weight = compute_binding(means, anchors)
    shift = torch.tensor([0.1, -0.2, 0.3])
    moved = deform_means(means, anchors, (anchors + shift)[None, None], index, weight)
    assert moved.shape == (1, 1, 25, 3)
    assert torch.allclose(moved[0, 0], means + shift, atol=1e-6)
    # A Gaussian sitting on an anchor follows that anchor alone.
    index, weight = compute_binding(anchors[:1], anchors)
    kick = torch.zeros_like(anchors)
    kick[0] = 1.0
    assert torch.allclose(
        deform_means(anchors[:1], anchors, anchors + kick, index, weight),
        anchors[:1] + 1.0,
        atol=1e-5,
    )
