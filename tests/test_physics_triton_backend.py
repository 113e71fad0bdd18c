"""The Triton engine (physics/triton_backend.py) against the PyTorch engine.

Without a GPU the kernels run in Triton's CPU interpreter (a subprocess with TRITON_INTERPRET=1);
with CUDA and Triton they are compiled. Either way they must give the reference's trajectories
and gradients up to float round-off.
"""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from reconphys.physics import knn_springs
from reconphys.physics.triton_backend import adjacency_table

HAVE_TRITON = importlib.util.find_spec("triton") is not None


def test_adjacency_table_lists_every_spring_at_both_ends():
    points = torch.rand(40, 3, generator=torch.Generator().manual_seed(0))
    springs, _ = knn_springs(points, 5)
    other, spring = adjacency_table(springs, 40)
    assert other.shape == spring.shape and other.shape[:2] == (1, 40)
    degree = torch.bincount(springs.reshape(-1), minlength=40)
    assert other.shape[2] == degree.max()
    assert torch.equal((other[0] >= 0).sum(1), degree)
    entries = set()
    for anchor in range(40):
        for o, s in zip(other[0, anchor].tolist(), spring[0, anchor].tolist(), strict=True):
            if o < 0:
                assert s == -1
                continue
            assert {anchor, o} == set(springs[s].tolist())
            entries.add((anchor, s))
    assert len(entries) == 2 * len(springs)


def test_adjacency_table_per_scene_topology():
    springs = torch.tensor([[[0, 1], [1, 2]], [[0, 2], [0, 1]]])
    other, spring = adjacency_table(springs, 3)
    assert other.shape == spring.shape == (2, 3, 2)
    assert sorted(other[1, 0].tolist()) == [1, 2]
    assert other[0, 0].tolist() == [1, -1]


@pytest.mark.skipif(not HAVE_TRITON, reason="needs Triton (pip install triton)")
@pytest.mark.slow
def test_fused_matches_torch_engine():
    device = "cuda" if torch.cuda.is_available() else "cpu"
    env = dict(os.environ)
    if device == "cpu":
        env["TRITON_INTERPRET"] = "1"
    script = Path(__file__).with_name("triton_compare.py")
    completed = subprocess.run(
        [sys.executable, str(script), "--device", device],
        env=env,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert completed.returncode == 0, completed.stderr[-3000:]
    results = json.loads(completed.stdout.strip().splitlines()[-1])
    for name, result in results.items():
        float64 = name.startswith("float64")
        assert result["contacts"] > 0, f"{name}: no ground contact in the window"
        assert result["x"] < (1e-12 if float64 else 1e-5), (name, result)
        assert result["v"] < (1e-11 if float64 else 1e-4), (name, result)
        for attribute, error in result["grads"].items():
            assert error < (1e-9 if float64 else 1e-4), (name, attribute, error)
