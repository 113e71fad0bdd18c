"""The Python API: ``from reconphys import Asset, read_asset`` and ``Asset.simulate``."""

from __future__ import annotations

import subprocess
import sys

import pytest
import torch
from typer.testing import CliRunner

from reconphys.cli import app

SMALL = ["--num-gaussians", "300", "--num-anchors", "40", "--neighbors", "8"]
SMALL += ["--min-substeps", "10"]


@pytest.fixture(scope="module")
def asset_dir(tmp_path_factory):
    out = tmp_path_factory.mktemp("api") / "asset"
    result = CliRunner().invoke(app, ["make-asset", str(out), "--shape", "box", *SMALL])
    assert result.exit_code == 0, result.output
    return out


def test_asset_simulate_equals_the_rollout(asset_dir):
    from reconphys import Asset, read_asset
    from reconphys.physics import rollout

    asset = read_asset(asset_dir)
    assert isinstance(asset, Asset)
    trajectory = asset.simulate(6)
    with torch.no_grad():
        reference = rollout(
            asset.model(),
            asset.initial_state(),
            6,
            frame_dt=asset.physics.frame_dt,
            min_substeps=asset.physics.substeps,
        )
    assert trajectory.x.shape == (1, 7, 40, 3)
    torch.testing.assert_close(trajectory.x, reference.x, rtol=0, atol=0)
    torch.testing.assert_close(trajectory.v, reference.v, rtol=0, atol=0)
    assert trajectory.substeps == reference.substeps >= 10
    assert trajectory.frame_dt == asset.physics.frame_dt
    # Frame 0 is the initial state; the object falls under gravity.
    torch.testing.assert_close(trajectory.x[0, 0], asset.x0)
    assert trajectory.x[0, -1, :, 2].mean() < asset.x0[:, 2].mean() - 0.01


def test_asset_simulate_rejects_zero_frames(asset_dir):
    from reconphys import read_asset
    from reconphys.errors import InputError

    with pytest.raises(InputError, match="frames"):
        read_asset(asset_dir).simulate(0)


def test_import_reconphys_stays_light():
    code = "import sys, reconphys; print('torch' in sys.modules); print(reconphys.Asset.__name__)"
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert result.returncode == 0, result.stderr
    assert result.stdout.split() == ["False", "Asset"]
