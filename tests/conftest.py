"""Shared fixtures (small deterministic anchor sets for physics tests) and the ``cuda`` marker:
a test marked ``@pytest.mark.cuda`` is skipped where no CUDA device is available."""

from __future__ import annotations

import socket

import pytest
import torch
from helpers import ball_points, make_small_asset

from reconphys.physics import knn_springs, sample_volume_anchors


@pytest.fixture(scope="session")
def ball_anchors():
    """128 volume anchors of a ball of radius 0.2 m and their K = 16 springs (float64)."""
    anchors = sample_volume_anchors(ball_points(4000, 0.2), 128, seed="test-ball").double()
    springs, _ = knn_springs(anchors, 16)
    rest = (anchors[springs[:, 1]] - anchors[springs[:, 0]]).norm(dim=1)
    return anchors, springs, rest


@pytest.fixture(scope="session")
def small_asset_dir(tmp_path_factory):
    """One small sphere asset folder (tests/helpers.py SMALL_ASSET) shared by the command-line
    tests; read-only: a test that changes an asset makes its own."""
    return make_small_asset(tmp_path_factory.mktemp("small") / "asset")


@pytest.fixture
def no_network(monkeypatch):
    """Any attempt to open a network connection fails the test."""

    def refuse(*args, **kwargs):
        raise AssertionError("a test touched the network")

    monkeypatch.setattr(socket.socket, "connect", refuse)


@pytest.fixture(autouse=True, scope="session")
def _flush_denormals():
    # Settling objects drive velocities into float32 denormals, which are ~100x slower on CPU.
    torch.set_flush_denormal(True)


def pytest_collection_modifyitems(config, items):
    if torch.cuda.is_available():
        return
    skip = pytest.mark.skip(reason="needs CUDA")
    for item in items:
        if "cuda" in item.keywords:
            item.add_marker(skip)
