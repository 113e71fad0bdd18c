"""The initial spin read from the free fall (pipeline/spin.py), against the simulator's own
free fall: the rigid model it assumes, and the roll it reads back from rendered frames."""

from __future__ import annotations

from dataclasses import replace

import pytest
import torch
from helpers import make_tiny_dataset

from reconphys.assets.gaussians import Gaussians
from reconphys.capture.camera import default_camera
from reconphys.geometry import rigid_velocity
from reconphys.pipeline.spin import ROLL_AXES, spin_fit, turned
from reconphys.render import render

SIZE = 64  # pixels
FRAMES = 9  # frames 0..8, all before the (removed) ground


@pytest.fixture(scope="module")
def asset(tmp_path_factory):
    from reconphys.data.dataset import DropDataset

    folder = make_tiny_dataset(tmp_path_factory.mktemp("spin") / "data", seed=5)
    asset = DropDataset(folder).asset(0)
    return replace(asset, physics=replace(asset.physics, ground_height=-10.0))  # no contact


def _launched(asset, linear, angular):
    """The asset with a rigid initial velocity about its Gaussians' centre (as predict builds)."""
    centre = asset.gaussians.means.mean(0)
    return replace(asset, v0=rigid_velocity(asset.x0, linear, angular, centre))


def _recorded(asset):
    """Frames (object on black) and masks of the simulator's rollout, seen by view 0."""
    camera = default_camera(SIZE, SIZE)
    means = asset.gaussian_means(asset.simulate(FRAMES - 1).x[0])
    frames, masks = [], []
    for t in range(FRAMES):
        out = render(asset.gaussians.with_means(means[t]), camera.cameras())
        mask = (out.alpha[0].reshape(SIZE, SIZE) > 0.5).float()
        frames.append(out.rgb[0] * mask[..., None])
        masks.append(mask)
    return torch.stack(frames), torch.stack(masks), camera


def test_the_rigid_free_fall_is_the_simulators(asset):
    """Before contact the spring-mass rollout of a rigid initial velocity is the closed form the
    fit renders: turned by ω·t about the centre, carried by v·t + ½·g·t² (to a few mm at
    1.5 rad/s: the springs stretch a little as it turns)."""
    linear = torch.tensor([0.2, -0.3, 0.5])
    angular = torch.tensor([0.4, -1.0, 0.9])
    launched = _launched(asset, linear, angular)
    x = launched.simulate(FRAMES - 1).x[0]  # [T, N_A, 3]
    centre = asset.gaussians.means.mean(0)
    x0 = asset.x0
    # the anchors as Gaussians, carried by their own centre's velocity
    points = Gaussians.from_activated(
        x0, torch.full_like(x0, 0.01), torch.full((len(x0),), 0.5), torch.full_like(x0, 0.5)
    )
    own = linear + torch.linalg.cross(angular, x0.mean(0) - centre)
    times = torch.arange(1, FRAMES, dtype=torch.float64) * asset.physics.frame_dt
    moved = turned(points, angular[None].double(), own, times).means
    assert float((moved - x[1:]).norm(dim=-1).max()) < 3e-3
    still = turned(points, torch.zeros(1, 3, dtype=torch.float64), own, times).means
    assert float((still - x[1:]).norm(dim=-1).max()) > 0.02  # the spin is not negligible


@pytest.mark.parametrize("roll", [1.5, -1.0, 0.0])
def test_the_roll_is_read_from_the_free_fall(asset, roll):
    """A turn about the viewing axis, simulated and rendered, is read back from the masked frames
    to a tenth of its size (a few tenths of a rad/s), from a linear velocity a little off; no
    turn reads as (nearly) none."""
    camera = default_camera(SIZE, SIZE)
    view_axis = camera.world_to_cam[2, :3].float()
    linear = torch.tensor([0.0, 0.3, 0.4])
    frames, masks, camera = _recorded(_launched(asset, linear, roll * view_axis))
    given = linear + torch.tensor([0.0, 0.05, -0.05])  # as the masks' fit would be off
    fit = spin_fit(asset.gaussians, frames, masks, camera, 0.03, given, FRAMES, axes=ROLL_AXES)
    read = float(view_axis.double() @ fit.angular)
    assert abs(read - roll) < 0.25, (read, roll)
    assert fit.shown == (roll != 0.0)
    if roll:
        assert fit.gain > 0.1
    # only the viewing axis is searched: no turn about the image's axes comes back
    across = fit.angular - (view_axis.double() @ fit.angular) * view_axis.double()
    assert float(across.norm()) < 1e-6


def test_too_short_a_fall_reads_no_spin(asset):
    frames, masks, camera = _recorded(_launched(asset, torch.zeros(3), torch.tensor([0, 0, 1.0])))
    fit = spin_fit(asset.gaussians, frames, masks, camera, 0.03, torch.zeros(3), 3)
    assert not fit.shown and fit.frames == 2 and not bool(fit.angular.any())
