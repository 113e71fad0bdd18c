"""Dataset randomness and planning: attribute ranges, orientations, drop heights, splits, shards."""

from __future__ import annotations

import math
import socket

import numpy as np
import pytest
import torch

from reconphys.data.plan import in_shard, parse_shard, plan_objects, plan_samples
from reconphys.data.sampling import (
    axis_angle_matrices,
    centroid_height_for_contact,
    contact_frame,
    draw_sample,
    random_rotation,
    toss_path_budget,
    toss_travel,
)
from reconphys.data.settings import DataSettings, make_settings
from reconphys.data.sources import ProceduralSource
from reconphys.data.stats import simulated_contact_frames
from reconphys.errors import InputError
from reconphys.physics import ATTRIBUTE_RANGES

F64 = torch.float64


@pytest.fixture(autouse=True)
def _no_network(monkeypatch):
    def refuse(*args, **kwargs):
        raise AssertionError("a test touched the network")

    monkeypatch.setattr(socket.socket, "connect", refuse)


@pytest.mark.parametrize("distribution", ["uniform", "log-uniform"])
def test_attributes_lie_in_design_ranges(distribution):
    settings = make_settings(distribution=distribution)
    specs = [draw_sample(settings, f"obj-{i}", j) for i in range(100) for j in range(4)]
    for name, (low, high) in ATTRIBUTE_RANGES.items():
        values = np.array([s.attributes[name] for s in specs])
        assert values.min() >= low and values.max() <= high, name
        middle = math.sqrt(low * high) if distribution == "log-uniform" and low > 0 else None
        if name != "friction" and middle is not None:
            assert abs(np.log(np.median(values) / middle)) < 0.35, name  # log-uniform median
        elif name != "friction":
            assert abs(np.median(values) - (low + high) / 2) < 0.12 * (high - low), name


def test_samples_are_deterministic_and_independent():
    settings = DataSettings()
    a = draw_sample(settings, "bunny-0001", 3)
    b = draw_sample(settings, "bunny-0001", 3)
    assert a.attributes == b.attributes and np.array_equal(a.rotation, b.rotation)
    assert draw_sample(settings, "bunny-0001", 4).attributes != a.attributes
    other_seed = DataSettings(seed=1)
    assert draw_sample(other_seed, "bunny-0001", 3).attributes != a.attributes


def test_sampled_motion_respects_its_bounds():
    settings = DataSettings()
    for i in range(200):
        spec = draw_sample(settings, "x", i)
        vx, vy, vz = spec.linear_velocity
        if spec.launch == "drop":
            assert max(abs(vx), abs(vy)) <= settings.max_horizontal_speed and spec.start == (0, 0)
        else:  # a toss: at most the range's top speed, starting behind the origin
            assert math.hypot(vx, vy) <= settings.toss_speed_range[1] + 1e-12
            assert vx * spec.start[0] + vy * spec.start[1] < 0
        assert abs(vz) <= settings.max_vertical_speed + 1e-12
        assert np.linalg.norm(spec.angular_velocity) <= settings.max_angular_speed
        t_c = spec.target_contact_time / settings.frame_dt
        assert settings.contact_frame_range[0] <= t_c <= settings.contact_frame_range[1]
        fall = 0.5 * 9.8 * spec.target_contact_time**2 - vz * spec.target_contact_time
        low, high = settings.drop_height_range
        assert low - 1e-9 <= fall <= high + 1e-9
        rotation = spec.rotation
        assert np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(rotation) == pytest.approx(1.0)


def test_launches_mix_drops_and_tosses_and_the_paper_preset_releases_from_rest():
    settings = DataSettings()
    specs = [draw_sample(settings, f"obj-{i}", j) for i in range(100) for j in range(4)]
    tosses = [s for s in specs if s.launch == "toss"]
    assert (
        0.42 < len(tosses) / len(specs) < 0.58
    )  # about half each (docs/design.md#attribute-ranges)
    speeds = np.array([math.hypot(*s.linear_velocity[:2]) for s in tosses])
    low, high = settings.toss_speed_range
    assert speeds.max() <= high + 1e-12 and np.median(speeds) > low  # lowered only to fit the view
    budget = toss_path_budget(settings)
    duration = (settings.num_frames - 1) * settings.frame_dt
    for s, speed in zip(tosses, speeds, strict=True):
        travel = toss_travel(speed, s.friction, s.target_contact_time, duration)
        assert travel <= budget + 1e-9
        assert math.hypot(*s.start) == pytest.approx(travel / 2)  # the path centred on the origin
    paper = make_settings("paper")
    for i in range(50):
        s = draw_sample(paper, "obj", i)
        assert s.launch == "drop" and s.linear_velocity == (0, 0, 0) and s.start == (0, 0)
        assert not np.any(s.angular_velocity)
        fall = 0.5 * 9.8 * s.target_contact_time**2
        assert paper.drop_height_range[0] <= fall <= paper.drop_height_range[1]


@pytest.mark.parametrize("friction", [0.0, 0.3])
def test_toss_travel_against_the_simulator(friction):
    """A stiff cube tossed sideways: with no friction its centroid covers exactly
    :func:`toss_travel`'s distance; with friction, at most that (the bound the aim relies on)."""
    from reconphys.physics import SpringMassModel, State, knn_springs, rollout

    grid = torch.stack(torch.meshgrid(*[torch.linspace(-0.05, 0.05, 3)] * 3, indexing="ij"), -1)
    anchors = grid.reshape(-1, 3).double()
    springs, rest = knn_springs(anchors, 8)
    contact_time, duration, speed, frame_dt = 0.3, 0.87, 1.0, 0.03
    x0 = anchors + torch.tensor([0.0, 0.0, 0.05 + 0.5 * 9.8 * contact_time**2], dtype=F64)
    v0 = torch.zeros_like(x0) + torch.tensor([speed, 0.0, 0.0], dtype=F64)
    model = SpringMassModel(springs, rest, 0.05, 1000.0, 1.0, friction, dtype=F64)
    frames = round(duration / frame_dt)
    traj = rollout(model, State(x0[None], v0[None]), frames, frame_dt, method="autograd")
    moved = (traj.x[0, -1, :, 0].mean() - traj.x[0, 0, :, 0].mean()).item()
    bound = toss_travel(speed, friction, contact_time, frames * frame_dt)
    if friction == 0.0:
        assert moved == pytest.approx(bound, rel=1e-3)
    else:
        assert 0.3 * bound < moved <= bound


def test_random_rotations_are_uniform_on_average():
    rng = np.random.default_rng(0)
    mean = np.mean([random_rotation(rng) for _ in range(4000)], axis=0)
    assert np.abs(mean).max() < 0.05  # E[R] = 0 for the Haar measure


def test_drop_height_without_rotation_is_free_fall():
    relative = np.array([[0.0, 0.0, -0.2], [0.1, 0.0, 0.2]])
    height = centroid_height_for_contact(relative, 0.5, (0.0, 0.0, 0.0), 0.3)
    assert height == pytest.approx(0.5 * 9.8 * 0.3**2 - 0.5 * 0.3 + 0.2)


def test_drop_height_accounts_for_rotation():
    # A bar along x spinning about y: its lowest point dips by up to half its length.
    bar = np.array([[-0.25, 0.0, 0.0], [0.25, 0.0, 0.0]])
    still = centroid_height_for_contact(bar, 0.0, (0.0, 0.0, 0.0), 0.3)
    spinning = centroid_height_for_contact(bar, 0.0, (0.0, 5.0, 0.0), 0.3)
    assert spinning > still
    times = np.linspace(0, 0.3, 2000)
    rotations = axis_angle_matrices(times[:, None] * np.array([0.0, 5.0, 0.0]))
    heights = spinning - 0.5 * 9.8 * times**2 + (bar @ rotations[:, 2, :].T).min(0)
    assert abs(heights.min()) < 2e-3  # touches (never sinks below) the ground by t_c


def test_simulated_samples_touch_the_ground_mid_clip():
    settings = make_settings(
        objects=6, samples_per_object=2, num_gaussians=200, num_anchors=32, num_neighbors=8
    )
    frames = [frame for _, frame in simulated_contact_frames(settings)]
    assert len(frames) == 12 and all(5 <= f <= 20 for f in frames), frames


def test_contact_frame():
    anchors = np.ones((30, 5, 3))
    anchors[12:, 2, 2] = 0.0005
    assert contact_frame(anchors) == 12
    assert contact_frame(np.ones((30, 5, 3))) == -1


def test_plan_splits_by_object_and_is_deterministic():
    settings = make_settings(objects=9, test_objects=3, samples_per_object=3)
    objects = plan_objects(settings, ProceduralSource())
    assert [o.split for o in objects] == ["train"] * 9 + ["test"] * 3
    assert len({o.ref.id for o in objects}) == 12
    samples = plan_samples(settings, objects)
    assert len(samples) == 9 * 3 + 3 * 2
    by_object = {}
    for s in samples:
        by_object.setdefault(s.object.ref.id, set()).add(s.split)
    assert all(len(splits) == 1 for splits in by_object.values())
    again = plan_objects(settings, ProceduralSource())
    assert [o.ref.id for o in again] == [o.ref.id for o in objects]
    reseeded = plan_objects(make_settings(objects=9, test_objects=3, seed=5), ProceduralSource())
    assert [o.ref.id for o in reseeded] != [o.ref.id for o in objects]


def test_shards_partition_the_objects():
    objects = plan_objects(make_settings(objects=10, test_objects=3), ProceduralSource())
    owners = [[in_shard(o, (i, 3)) for i in range(3)] for o in objects]
    assert all(sum(row) == 1 for row in owners)
    assert parse_shard("1/4") == (1, 4) and parse_shard(None) is None
    for bad in ("4/4", "x", "-1/2", "1/0"):
        with pytest.raises(InputError, match="--shard"):
            parse_shard(bad)


def test_settings_are_validated():
    with pytest.raises(InputError, match="--distribution"):
        make_settings(distribution="gaussian")
    with pytest.raises(InputError, match="--preset"):
        make_settings("huge")
    with pytest.raises(InputError, match="stiffness_range"):
        make_settings(stiffness_range=(5.0, 1200.0))
    with pytest.raises(InputError, match="--objects"):
        make_settings(objects=0, test_objects=0)
    with pytest.raises(InputError, match="--max-horizontal-speed"):
        make_settings(max_horizontal_speed=-0.1)
    with pytest.raises(InputError, match="--max-angular-speed"):
        make_settings(max_angular_speed=float("nan"))
    paper = make_settings("paper")
    assert (paper.objects, paper.samples_per_object, paper.test_objects) == (450, 10, 46)
    assert (paper.test_samples_per_object, paper.resolution, paper.num_anchors) == (2, 512, 2048)
    assert DataSettings.from_dict(paper.to_dict()) == paper
    assert paper.fingerprint() != DataSettings().fingerprint()


def test_rotation_matrix_of_zero_vector_is_identity():
    assert np.allclose(axis_angle_matrices(np.zeros((1, 3)))[0], np.eye(3))
