"""The Numba engine (physics/numba_backend.py) against the plain PyTorch reference."""

from __future__ import annotations

import pytest
import torch
from test_physics_adjoint import F64, small_system, trajectories

from reconphys._optional import numba_available
from reconphys.physics import SpringMassModel, State, rollout
from reconphys.physics.state import Control

pytestmark = pytest.mark.skipif(not numba_available(), reason="needs Numba")


@pytest.mark.parametrize(
    "exponent, restitution, per_scene, dtype",
    [
        (0.5, 0.0, False, torch.float64),
        (0.0, 0.5, False, torch.float64),
        (0.3, 0.2, True, torch.float64),
        (0.5, 0.0, False, torch.float32),
    ],
)
def test_compiled_substeps_match_reference(exponent, restitution, per_scene, dtype):
    springs, rest, x0, v0, attributes = small_system(per_scene_topology=per_scene, dtype=dtype)
    model = SpringMassModel(
        springs, rest, **attributes, spring_exponent=exponent, restitution=restitution, dtype=dtype
    )
    state = State(x0, v0)
    reference = rollout(model, state, 6, substeps=8, method="autograd")
    compiled = rollout(model, state, 6, substeps=8, method="numba")
    assert (reference.x[..., 2] <= 1e-12).any(), "the window must include ground contact"
    tolerance = 1e-12 if dtype == torch.float64 else 2e-6
    assert compiled.x.dtype == dtype and compiled.substeps == 8
    torch.testing.assert_close(compiled.x, reference.x, rtol=0, atol=tolerance)
    torch.testing.assert_close(compiled.v, reference.v, rtol=0, atol=100 * tolerance)


def test_compiled_substeps_take_a_control_force():
    springs, rest, x0, v0, attributes = small_system(batch=1)
    model = SpringMassModel(springs, rest, **attributes, dtype=torch.float64)
    force = torch.zeros_like(x0)
    force[:, :3] = torch.tensor([5.0, 0.0, 20.0], dtype=torch.float64)
    control = Control(force=force)
    reference = rollout(model, State(x0, v0), 4, substeps=6, control=control, method="autograd")
    compiled = rollout(model, State(x0, v0), 4, substeps=6, control=control, method="numba")
    torch.testing.assert_close(compiled.x, reference.x, rtol=0, atol=1e-12)
    free = rollout(model, State(x0, v0), 4, substeps=6, method="numba")
    assert (compiled.x - free.x).abs().max() > 1e-3  # the force did something


@pytest.mark.parametrize(
    "exponent, restitution, per_scene", [(0.5, 0.0, False), (0.0, 0.5, False), (0.3, 0.3, True)]
)
def test_compiled_backward_matches_the_torch_adjoint(exponent, restitution, per_scene):
    """The compiled VJP (contact, free update, springs) against the hand-written torch one, which
    test_physics_adjoint checks against autograd: every input's gradient, float64."""
    system = small_system(per_scene_topology=per_scene)
    reference, grads_ref = trajectories("adjoint", *system, exponent, restitution)
    compiled, grads = trajectories("numba", *system, exponent, restitution)
    assert (reference.x[..., 2] <= 1e-12).any(), "the window must include ground contact"
    torch.testing.assert_close(compiled.x, reference.x, rtol=0, atol=1e-13)
    for name, expected in grads_ref.items():
        assert grads[name].shape == expected.shape, name
        assert expected.abs().max() > 0, name
        error = (grads[name] - expected).abs().max() / expected.abs().max()
        assert error < 1e-12, f"{name}: relative error {error:.2e}"


def test_compiled_backward_gradcheck_with_contact():
    springs, rest, x0, v0, attributes = small_system(num_anchors=10, batch=1)

    def run(v0, mass, stiffness, damping, friction, rest):
        model = SpringMassModel(springs, rest, mass, stiffness, damping, friction, dtype=F64)
        traj = rollout(model, State(x0, v0), 2, substeps=3, method="numba")
        return traj.x[:, -1], traj.v[:, -1]

    inputs = [v0, *attributes.values(), rest]
    inputs = [t.clone().requires_grad_(True) for t in inputs]
    assert torch.autograd.gradcheck(run, inputs, eps=1e-7, atol=1e-6, rtol=1e-5)


def test_compiled_backward_in_float32_and_with_broadcast_attributes():
    """x0 [1, N, 3] shared by 3 attribute sets, scalar stiffness/friction, rest [E], float32."""
    springs, rest, x0, v0, _ = small_system(batch=1)
    attributes = {
        "mass": torch.tensor([0.5, 1.0, 2.0]),
        "stiffness": torch.tensor(80.0),
        "damping": torch.tensor([0.5, 1.0, 2.0]),
        "friction": torch.tensor(0.4),
    }
    system = (springs, rest.float(), x0.float(), v0.float(), attributes)
    _, grads_ref = trajectories("adjoint", *system)
    compiled, grads = trajectories("numba", *system)
    assert compiled.x.shape[0] == 3 and compiled.x.dtype == torch.float32
    for name, expected in grads_ref.items():
        assert grads[name].shape == expected.shape and grads[name].dtype == torch.float32, name
        error = (grads[name] - expected).abs().max() / expected.abs().max()
        assert error < 1e-4, f"{name}: relative error {error:.2e}"


def test_numba_refuses_a_control_force_with_gradients():
    springs, rest, x0, v0, attributes = small_system(batch=1)
    model = SpringMassModel(springs, rest, **attributes, dtype=torch.float64)
    control = Control(force=torch.zeros_like(x0))
    with pytest.raises(ValueError, match="only without gradients"):
        state = State(x0, v0.requires_grad_(True))
        rollout(model, state, 1, substeps=2, control=control, method="numba")


def test_parallel_result_does_not_depend_on_the_thread_count(monkeypatch):
    import numba

    from reconphys.physics import numba_backend

    monkeypatch.setattr(numba_backend, "PARALLEL_MIN_SPRINGS", 0)  # force the parallel build
    springs, rest, x0, v0, attributes = small_system()
    model = SpringMassModel(springs, rest, **attributes, dtype=torch.float64)
    results = []
    threads = numba.get_num_threads()
    try:
        for count in (1, threads):
            numba.set_num_threads(count)
            results.append(rollout(model, State(x0, v0), 3, substeps=5, method="numba").x)
    finally:
        numba.set_num_threads(threads)
    assert torch.equal(results[0], results[1])
    reference = rollout(model, State(x0, v0), 3, substeps=5, method="autograd")
    torch.testing.assert_close(results[0], reference.x, rtol=0, atol=1e-12)


def test_every_cached_kernel_has_its_own_cache_entry():
    """Numba's on-disk cache keys a kernel by its function's name and line, not its compile
    options: the parallel and serial builds of the substep must not share an entry, or whichever
    a process compiles first (a small, serial simulation) is what later processes load for the
    parallel path too. Checked for every cached kernel of the simulator and the renderer."""
    from numba.core.registry import CPUDispatcher

    from reconphys.physics import anchors
    from reconphys.physics import numba_backend as physics_kernels
    from reconphys.render import numba_backend as render_kernels

    namespaces = [vars(m) for m in (physics_kernels, render_kernels, anchors)]
    namespaces += [vars(physics_kernels.PARALLEL), vars(physics_kernels.SERIAL)]
    kernels = {
        f"{id(namespace)}.{name}": value
        for namespace in namespaces
        for name, value in namespace.items()
        if isinstance(value, CPUDispatcher) and value._cache is not None
    }
    assert len(kernels) >= 18
    names = [k._cache._cache_file._index_name for k in kernels.values()]
    assert len(set(names)) == len(names), dict(zip(kernels, names, strict=True))
    for name in physics_kernels._KERNELS:
        assert getattr(physics_kernels.PARALLEL, name).targetoptions["parallel"] is True
        assert not getattr(physics_kernels.SERIAL, name).targetoptions.get("parallel", False)


def test_anchors_are_renumbered_along_the_springs():
    """The engine numbers anchors so that springs join near numbers (reverse Cuthill–McKee): a
    permutation, undone on the way out (the tests above compare per-anchor values), that brings a
    random volume's spring ends ≥ 3× closer in index."""
    import numpy as np

    from reconphys.physics import knn_springs, sample_volume_anchors
    from reconphys.physics.numba_backend import NumbaEngine

    points = torch.rand(4000, 3, generator=torch.Generator().manual_seed(1))
    anchors = sample_volume_anchors(points, 256, seed="renumber")
    springs, rest = knn_springs(anchors, 12)
    model = SpringMassModel(springs, rest, torch.tensor(1.0), 100.0, 1.0, 0.5)
    engine = NumbaEngine(model, 1e-4, 1, 256)
    order = engine.anchor_order[0]
    assert np.array_equal(np.sort(order), np.arange(256)) and not np.array_equal(
        order, np.arange(256)
    )
    first, second = (engine.topology[n][0].astype(np.int64) // 3 for n in (0, 1))
    spread = np.abs(first - second).mean()
    assert spread * 3 < (springs[:, 0] - springs[:, 1]).abs().double().mean().item()
