"""Our spring-mass simulator side by side with NVIDIA Warp on CPU: the same substep, both engines.

The system is bench_simulator.py's (``make_system``): one scene, 2,048 volume anchors in a 0.5 m
ball, K = 32 nearest-neighbour springs (~36k), mass 1, stiffness 300, damping 1, friction 0.5,
float32, starting 0.26 m up. The substep length is the one our rollout picks for 30 ms frames
(``stable_substeps``, 1.875 ms here), so the ball reaches the ground within the first ~30 of the
300 substeps and the comparison covers contact and friction.

Warp twin: the substep of ``physics.reference.step`` written as two kernels, one thread per spring
(non-linear spring and dashpot, ``wp.atomic_add`` of ±force into a ``wp.vec3`` force array) and one
thread per anchor (semi-implicit Euler, then ground contact with restitution and friction), x/v
ping-ponged between two buffers. The spring exponent is fixed at code generation (``wp.sqrt`` for
the model's p = 0.5, ``wp.pow`` otherwise). Warp runs CPU kernels on one thread.

How Warp's CPU path is driven: graph capture. Since Warp 1.13 ``wp.ScopedCapture(device="cpu")``
records launches, memsets and copies into an operation stream that ``wp.capture_launch`` replays
in a C++ loop, with no Python per launch; since 1.14 the stream may hold ``Tape.backward`` too.
So the forward (reset, then S × [clear forces, spring kernel, integrate kernel]) is captured once
and replayed, and so is the whole forward + backward (gradient clears, taped substeps, loss,
``tape.backward``). Where a Warp build cannot capture, the forward falls back to pre-recorded
launches (``wp.launch(..., record_cmd=True)``, then ``.launch()``) and the backward to an eager
tape; ``--recorded`` forces that path, to see what capture saves (little here: a substep's two
kernels take ~0.3 ms, far above the launch cost).

Forward + backward on Warp is ``wp.Tape`` over S substeps with every substep's state (and force
array) kept, loss = sum of the final z, gradients to k, d, mass, friction (per spring / per anchor
arrays) and the initial velocity. Ours: forward = ``rollout(..., method="numba")`` under no_grad,
forward + backward = the same with gradients on (the compiled adjoint) and
``traj.x[:, -1, :, 2].sum().backward()`` as in bench_simulator.py. Our timings run in one
subprocess per thread count (NUMBA_NUM_THREADS and
torch threads set before Numba starts), Warp's in its own; rounds interleave them and the table
keeps each one's best. Agreement (final positions, gradient sums) is checked first: the script
exits non-zero if the positions differ by more than 1e-5 m.

    pip install -e .[bench]                          # warp-lang
    python benchmarks/bench_vs_warp.py               # ~2-7 min on 2 cores
    python benchmarks/bench_vs_warp.py --threads 1 2 4 --substeps 300 --rounds 3
    python benchmarks/bench_vs_warp.py --recorded    # Warp without graph capture
"""

from __future__ import annotations

import argparse
import datetime
import importlib.util
import json
import os
import subprocess
import sys
import time
from functools import cache
from pathlib import Path

import numpy as np

FRAME_DT = 0.03  # rollout's default frame length: the substep length is what it would use
TOLERANCE = 1e-5  # metres, max |x_ours - x_warp| after all substeps
SYSTEM = (1, 2048, 32)  # scenes, anchors, neighbours: bench_simulator.py's --quick CPU row

MISSING_WARP = "bench_vs_warp.py needs NVIDIA Warp (warp-lang): pip install -e '.[bench]'"


# ---------------------------------------------------------------------------------------------
# Set-up shared by every worker
# ---------------------------------------------------------------------------------------------


def system(grad: bool, renumbered: bool = False):
    """bench_simulator.py's ball and the substep length our rollout would pick for 30 ms frames.

    ``renumbered``: anchors numbered as our engine numbers them internally (reverse Cuthill–McKee
    on the spring graph), so that Warp gets the same memory locality."""
    from bench_simulator import make_system

    from reconphys.physics import SpringMassModel, State
    from reconphys.physics.stability import stable_substeps

    model, state, params, num_springs = make_system(*SYSTEM, "cpu", grad)
    if renumbered:
        import torch

        from reconphys.physics.numba_backend import _anchor_order

        order = torch.from_numpy(_anchor_order(model.springs.numpy(), SYSTEM[1]))
        rank = torch.empty_like(order)
        rank[order] = torch.arange(len(order))
        model = SpringMassModel(rank[model.springs], model.rest_length, **params)
        v0 = state.v.detach()[:, order].requires_grad_(grad)
        state = State(state.x[:, order].contiguous(), v0)
    dt = FRAME_DT / stable_substeps(model, state.x.detach(), FRAME_DT)
    return model, state, params, num_springs, dt


def best_time(fn, repeats: int) -> float:
    from common import timed

    return timed(fn, "cpu", repeats=repeats)


# ---------------------------------------------------------------------------------------------
# Warp twin
# ---------------------------------------------------------------------------------------------


@cache
def warp_kernels(exponent: float):
    """The substep's two kernels and the loss, with the spring exponent p fixed at generation."""
    import warp as wp

    p = float(exponent)

    @wp.kernel(module="unique")
    def spring_forces(
        x: wp.array(dtype=wp.vec3),
        v: wp.array(dtype=wp.vec3),
        i: wp.array(dtype=wp.int32),
        j: wp.array(dtype=wp.int32),
        rest: wp.array(dtype=wp.float32),
        k: wp.array(dtype=wp.float32),
        d: wp.array(dtype=wp.float32),
        force: wp.array(dtype=wp.vec3),
    ):
        s = wp.tid()
        a = i[s]
        b = j[s]
        delta = x[b] - x[a]
        length = wp.sqrt(wp.dot(delta, delta) + 1.0e-24)
        direction = delta / length
        strain = length / rest[s] - 1.0
        magnitude = k[s] * strain
        if wp.static(p == 0.5):
            magnitude = magnitude * wp.sqrt(1.0 + wp.abs(strain))
        elif wp.static(p != 0.0):
            magnitude = magnitude * wp.pow(1.0 + wp.abs(strain), wp.float32(wp.static(p)))
        closing = wp.dot(v[b] - v[a], direction)
        magnitude = magnitude + d[s] / rest[s] * closing
        pull = magnitude * direction  # on a, towards b when stretched
        wp.atomic_add(force, a, pull)
        wp.atomic_sub(force, b, pull)

    @wp.kernel(module="unique")
    def integrate(
        x: wp.array(dtype=wp.vec3),
        v: wp.array(dtype=wp.vec3),
        force: wp.array(dtype=wp.vec3),
        mass: wp.array(dtype=wp.float32),
        friction: wp.array(dtype=wp.float32),
        gravity: wp.vec3,
        restitution: wp.float32,
        ground: wp.float32,
        dt: wp.float32,
        x_out: wp.array(dtype=wp.vec3),
        v_out: wp.array(dtype=wp.vec3),
    ):
        n = wp.tid()
        vf = v[n] + (force[n] / mass[n] + gravity) * dt
        xf = x[n] + vf * dt
        if xf[2] < ground:
            approach = wp.min(vf[2], 0.0)
            speed = wp.sqrt(vf[0] * vf[0] + vf[1] * vf[1] + 1.0e-30)
            retained = wp.max(1.0 + friction[n] * ((1.0 + restitution) * approach) / speed, 0.0)
            vt0 = vf[0] * retained
            vt1 = vf[1] * retained
            xf = wp.vec3(xf[0] - dt * (vf[0] - vt0), xf[1] - dt * (vf[1] - vt1), ground)
            vf = wp.vec3(vt0, vt1, vf[2] - (1.0 + restitution) * approach)
        x_out[n] = xf
        v_out[n] = vf

    @wp.kernel(module="unique")
    def height_sum(x: wp.array(dtype=wp.vec3), loss: wp.array(dtype=wp.float32)):
        wp.atomic_add(loss, 0, x[wp.tid()][2])

    return spring_forces, integrate, height_sum


class WarpTwin:
    """The model's substep on Warp arrays: a captured forward and a captured tape."""

    def __init__(self, model, state, dt: float, substeps: int, device: str, capture: bool):
        import warp as wp

        self.wp, self.device, self.substeps, self.capture = wp, device, substeps, capture
        self.captured = {}  # "forward" / "tape": whether capture worked
        self.kernels = warp_kernels(model.spring_exponent)
        springs = model.springs.cpu().numpy()
        num_springs, num_anchors = springs.shape[0], state.x.shape[1]
        self.num_anchors = num_anchors

        def values(t, count: int) -> np.ndarray:  # [1, 1] or [1, count] → [count] float32
            flat = t.detach().cpu().numpy().astype(np.float32).reshape(-1)
            return np.ascontiguousarray(np.broadcast_to(flat, (count,)))

        def array(values, dtype, grad=False):
            return wp.array(values, dtype=dtype, device=device, requires_grad=grad)

        self.i = array(springs[:, 0].astype(np.int32), wp.int32)
        self.j = array(springs[:, 1].astype(np.int32), wp.int32)
        self.rest = array(values(model.rest_length, num_springs), wp.float32)
        self.k = array(values(model.stiffness, num_springs), wp.float32, grad=True)
        self.d = array(values(model.damping, num_springs), wp.float32, grad=True)
        self.mass = array(values(model.mass, num_anchors), wp.float32, grad=True)
        self.friction = array(values(model.friction, num_anchors), wp.float32, grad=True)
        self.x0 = array(state.x.detach().cpu().numpy()[0], wp.vec3)
        self.v0 = array(state.v.detach().cpu().numpy()[0], wp.vec3, grad=True)
        self.scalars = (
            wp.vec3(*model.gravity),
            float(model.restitution),
            float(model.ground_height),
            float(dt),
        )
        self.num_springs = num_springs

    def captured_graph(self, name: str, work):
        """``work()`` captured into a graph: a function that replays it, or None where this Warp
        cannot capture it (CPU capture came in Warp 1.13, of ``Tape.backward`` in 1.14)."""
        wp = self.wp
        self.captured[name] = False
        if not self.capture:
            return None
        try:
            with wp.ScopedCapture(device=self.device) as capture:
                work()
        except Exception as error:
            print(f"(Warp cannot capture the {name} on {self.device}: {error})", file=sys.stderr)
            return None
        graph = capture.graph
        self.captured[name] = True

        def run():
            wp.capture_launch(graph)
            wp.synchronize_device(self.device)

        return run

    # -- one substep ------------------------------------------------------------------------

    def launch_substep(self, x, v, force, x_out, v_out, record: bool = False):
        wp = self.wp
        springs, integrate, _ = self.kernels
        spring_launch = wp.launch(
            springs,
            dim=self.num_springs,
            inputs=[x, v, self.i, self.j, self.rest, self.k, self.d],
            outputs=[force],
            device=self.device,
            record_cmd=record,
        )
        integrate_launch = wp.launch(
            integrate,
            dim=self.num_anchors,
            inputs=[x, v, force, self.mass, self.friction, *self.scalars],
            outputs=[x_out, v_out],
            device=self.device,
            record_cmd=record,
        )
        return spring_launch, integrate_launch

    # -- forward ----------------------------------------------------------------------------

    def forward(self):
        """A function that runs all substeps from the initial state, and the final positions."""
        wp = self.wp
        xs = [wp.empty_like(self.x0) for _ in range(2)]
        vs = [wp.empty_like(self.x0) for _ in range(2)]
        force = wp.zeros_like(self.x0)
        final = self.substeps % 2

        def substeps():
            wp.copy(xs[0], self.x0)
            wp.copy(vs[0], self.v0)
            for s in range(self.substeps):
                a, b = s % 2, (s + 1) % 2
                force.zero_()
                self.launch_substep(xs[a], vs[a], force, xs[b], vs[b])

        substeps()  # loads the modules (compiles on a cold cache)
        run = self.captured_graph("forward", substeps)
        if run is None:  # two recorded launch pairs serve every substep (ping-pong)
            pairs = [
                self.launch_substep(xs[a], vs[a], force, xs[1 - a], vs[1 - a], record=True)
                for a in (0, 1)
            ]

            def run():
                wp.copy(xs[0], self.x0)
                wp.copy(vs[0], self.v0)
                for s in range(self.substeps):
                    force.zero_()
                    for launch in pairs[s % 2]:
                        launch.launch()
                wp.synchronize_device(self.device)

        return run, xs[final]

    # -- forward + backward -----------------------------------------------------------------

    def forward_backward(self):
        """A function that runs taped substeps and the backward of the final height sum."""
        wp = self.wp
        count = self.substeps
        xs = [self.x0] + [wp.empty_like(self.x0, requires_grad=True) for _ in range(count)]
        vs = [self.v0] + [wp.empty_like(self.x0, requires_grad=True) for _ in range(count)]
        forces = [wp.zeros_like(self.x0, requires_grad=True) for _ in range(count)]
        loss = wp.zeros(1, dtype=wp.float32, device=self.device, requires_grad=True)
        arrays = [*xs[1:], *vs[1:], *forces, self.v0, self.k, self.d, self.mass, self.friction]
        arrays.append(loss)

        def taped():
            for a in arrays:
                a.grad.zero_()
            for f in forces:
                f.zero_()
            loss.zero_()
            tape = wp.Tape()
            with tape:
                for s in range(count):
                    self.launch_substep(xs[s], vs[s], forces[s], xs[s + 1], vs[s + 1])
                wp.launch(self.kernels[2], dim=self.num_anchors, inputs=[xs[-1]], outputs=[loss])
            tape.backward(loss)

        taped()  # loads the modules, forward and adjoint
        run = self.captured_graph("tape", taped)
        if run is None:

            def run():
                taped()
                wp.synchronize_device(self.device)

        grads = {"mass": self.mass, "stiffness": self.k, "damping": self.d}
        grads.update(friction=self.friction, v0=self.v0)
        return run, xs, grads


def warp_timings(model, state, dt, substeps, repeats, device, capture) -> dict:
    twin = WarpTwin(model, state, dt, substeps, device, capture)
    forward, _ = twin.forward()
    forward_backward, *_ = twin.forward_backward()
    return {
        "forward": substeps / best_time(forward, repeats),
        "backward": substeps / best_time(forward_backward, repeats),
        "captured": twin.captured,
    }


# ---------------------------------------------------------------------------------------------
# Workers (one process each)
# ---------------------------------------------------------------------------------------------


def ours_functions(model, state, dt, substeps):
    import torch

    from reconphys.physics import rollout

    frame_dt = dt * substeps  # one frame of `substeps` substeps: rollout's dt = frame_dt / substeps

    def forward():
        with torch.no_grad():
            return rollout(model, state, 1, frame_dt, substeps=substeps, method="numba")

    def forward_backward():
        traj = rollout(model, state, 1, frame_dt, substeps=substeps, method="numba")
        traj.x[:, -1, :, 2].sum().backward()
        return traj

    return forward, forward_backward


def worker_ours(args) -> dict:
    from reconphys.threads import set_cpu_threads

    set_cpu_threads(args.threads[0])
    model, state, _, _, dt = system(True, args.renumbered)
    forward, forward_backward = ours_functions(model, state, dt, args.substeps)
    return {
        "forward": args.substeps / best_time(forward, args.repeats),
        "backward": args.substeps / best_time(forward_backward, args.repeats),
    }


def worker_warp(args) -> dict:
    import warp as wp

    from reconphys.threads import set_cpu_threads

    set_cpu_threads(1)
    model, state, _, _, dt = system(False, args.renumbered)
    setting = (model, state, dt, args.substeps, args.repeats)
    result = {"cpu": warp_timings(*setting, "cpu", args.capture)}
    if wp.is_cuda_available():
        result["cuda"] = warp_timings(*setting, "cuda:0", True)
        result["gpu"] = wp.get_device("cuda:0").name
    return result


def worker_check(args) -> dict:
    """Final positions and gradients, ours and Warp's (CPU), and the contact on the way."""
    import torch
    import warp as wp

    from reconphys.threads import set_cpu_threads

    set_cpu_threads(1)
    model, state, params, num_springs, dt = system(True, args.renumbered)
    forward, forward_backward = ours_functions(model, state, dt, args.substeps)
    x_numba = forward().x[0, -1].numpy()
    traj = forward_backward()
    x_adjoint = traj.x[0, -1].detach().numpy()
    ours = {name: float(t.grad.sum()) for name, t in params.items()}
    ours["v0"] = state.v.grad[0].numpy()

    twin = WarpTwin(model, state, dt, args.substeps, "cpu", args.capture)
    run, x_final = twin.forward()
    run()
    x_warp = x_final.numpy()
    run_tape, xs, grads = twin.forward_backward()
    run_tape()
    heights = np.stack([x.numpy()[:, 2] for x in xs])  # [S + 1, N_A]
    ground = model.ground_height
    touching = (heights <= ground).any(axis=1)
    first_contact = int(np.argmax(touching)) if touching.any() else -1
    warp_grads = {name: a.grad.numpy() for name, a in grads.items()}

    def relative(a, b) -> float:
        return float(np.abs(a - b).max() / max(np.abs(b).max(), 1e-30))

    gradients = {
        name: {"warp": float(warp_grads[name].sum()), "ours": ours[name]}
        for name in ("stiffness", "damping", "mass", "friction")
    }
    for entry in gradients.values():
        entry["relative"] = relative(np.float64(entry["warp"]), np.float64(entry["ours"]))
    gradients["v0"] = {"relative": relative(warp_grads["v0"], ours["v0"])}
    return {
        "springs": num_springs,
        "dt": dt,
        "duration": dt * args.substeps,
        "start_min_z": float(heights[0].min()),
        "min_z": float(heights.min()),
        "ground": ground,
        "first_contact": first_contact,
        "on_ground_end": int((heights[-1] <= ground).sum()),
        "numba_vs_warp": float(np.abs(x_numba - x_warp).max()),
        "adjoint_vs_warp": float(np.abs(x_adjoint - x_warp).max()),
        "warp_tape_vs_graph": float(np.abs(xs[-1].numpy() - x_warp).max()),
        "gradients": gradients,
        "captured": twin.captured,
        "versions": {"warp": wp.__version__, "torch": torch.__version__},
    }


WORKERS = {"ours": worker_ours, "warp": worker_warp, "check": worker_check}


def run_worker(kind: str, threads: int, args) -> dict:
    """Run one worker in a fresh process with ``threads`` Numba/torch threads; its result dict."""
    command = [sys.executable, str(Path(__file__).resolve()), "--worker", kind]
    command += ["--threads", str(threads), "--substeps", str(args.substeps)]
    command += ["--repeats", str(args.repeats)]
    if not args.capture:
        command.append("--recorded")
    if args.renumbered:
        command.append("--renumbered")
    env = dict(os.environ, NUMBA_NUM_THREADS=str(threads), OMP_NUM_THREADS=str(threads))
    done = subprocess.run(command, env=env, capture_output=True, text=True, check=False)
    lines = [line for line in done.stdout.splitlines() if line.startswith("RESULT ")]
    if done.returncode != 0 or not lines:
        sys.stderr.write(done.stdout + done.stderr)
        raise SystemExit(f"bench_vs_warp.py: the {kind} worker ({threads} threads) failed")
    return json.loads(lines[-1][len("RESULT ") :])


# ---------------------------------------------------------------------------------------------
# Report
# ---------------------------------------------------------------------------------------------


def print_check(check: dict, substeps: int) -> bool:
    """Print the agreement section; True when the positions agree within TOLERANCE."""
    print(
        f"\n### Agreement after {substeps} substeps of {check['dt'] * 1e3:.3f} ms "
        f"({check['duration']:.3f} s), CPU, float32"
    )
    print(
        f"contact: lowest anchor starts at z = {check['start_min_z']:.4f} m, first touches the "
        f"ground (z = {check['ground']:g}) at substep {check['first_contact']}; min z reached "
        f"{check['min_z']:.6f} m; {check['on_ground_end']} anchors on the ground at the end"
    )
    print("\n| quantity | value | acceptance |")
    print("|---|---|---|")
    ok = check["numba_vs_warp"] <= TOLERANCE
    mark = "ok" if ok else "FAILED"
    value = f"{check['numba_vs_warp']:.2e} m"
    print(f"| max \\|x_ours − x_warp\\| (numba) | {value} | ≤ {TOLERANCE:.0e} m: {mark} |")
    value = f"{check['adjoint_vs_warp']:.2e} m"
    print(f"| max \\|x_ours − x_warp\\| (adjoint's forward) | {value} | — |")
    for name, g in check["gradients"].items():
        if name == "v0":
            value = f"max relative difference {g['relative']:.1e}"
            print(f"| d loss / d v0 (per anchor), Warp tape vs ours | {value} | — |")
        else:
            value = f"{g['warp']:.6g} vs {g['ours']:.6g} (relative {g['relative']:.1e})"
            print(f"| Σ d loss / d {name}, Warp tape vs ours | {value} | — |")
    return ok


def print_table(warp: dict, ours: dict, threads: list[int]) -> None:
    rows = {"forward": "forward", "backward": "forward + backward"}
    columns = ["Warp CPU (1 thread)"] + [f"ours, {n} thread{'s' * (n > 1)}" for n in threads]
    if "cuda" in warp:
        columns.append(f"Warp CUDA ({warp['gpu']})")
    print("\nsubsteps/s, best of all rounds; (×): ours / Warp CPU\n")
    print("| | " + " | ".join(columns) + " |")
    print("|---|" + "---|" * len(columns))
    for key, title in rows.items():
        base = warp["cpu"][key]
        cells = [f"{base:,.0f}"]
        cells += [f"{ours[n][key]:,.0f} ({ours[n][key] / base:.2f}×)" for n in threads]
        if "cuda" in warp:
            cells.append(f"{warp['cuda'][key]:,.0f}")
        print(f"| {title} | " + " | ".join(cells) + " |")


def best(results: list[dict]) -> dict:
    return {key: max(r[key] for r in results) for key in ("forward", "backward")}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--substeps", type=int, default=300, help="substeps per timing and check")
    parser.add_argument("--threads", type=int, nargs="+", default=[1, 2], help="ours: threads")
    parser.add_argument("--rounds", type=int, default=3, help="interleaved rounds (best kept)")
    parser.add_argument("--repeats", type=int, default=2, help="timings per round after warm-up")
    parser.add_argument(
        "--recorded", dest="capture", action="store_false", help="Warp without graph capture"
    )
    parser.add_argument(
        "--renumbered",
        action="store_true",
        help="give both engines the anchors in our engine's internal order (Warp's locality too)",
    )
    parser.add_argument("--worker", choices=sorted(WORKERS), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if importlib.util.find_spec("warp") is None:
        raise SystemExit(MISSING_WARP)
    if args.worker:
        import warp as wp

        wp.init()
        print("RESULT " + json.dumps(WORKERS[args.worker](args)), flush=True)
        return

    from common import machine_description

    start = time.perf_counter()
    check = run_worker("check", 1, args)  # also fills Warp's and Numba's kernel caches
    versions = check["versions"]
    print("## Ours vs NVIDIA Warp (CPU)")
    print(f"{datetime.date.today()}; {machine_description('cpu')}; warp {versions['warp']}")
    captured = check["captured"]
    mode = (
        f"forward: {'graph capture' if captured['forward'] else 'recorded launches'}, "
        f"forward + backward: {'graph capture' if captured['tape'] else 'eager tape'}"
    )
    print(
        f"1 scene, {SYSTEM[1]:,} anchors, K = {SYSTEM[2]} ({check['springs']:,} springs), float32; "
        f"Warp CPU driven by {mode}; anchors "
        + ("renumbered (our engine's order) for both" if args.renumbered else "as generated")
    )
    ok = print_check(check, args.substeps)

    warp_runs, ours_runs = [], {n: [] for n in args.threads}
    for _ in range(args.rounds):
        warp_runs.append(run_worker("warp", 1, args))
        for n in args.threads:
            ours_runs[n].append(run_worker("ours", n, args))
    warp = {"cpu": best([r["cpu"] for r in warp_runs])}
    if "cuda" in warp_runs[0]:
        warp["cuda"] = best([r["cuda"] for r in warp_runs])
        warp["gpu"] = warp_runs[0]["gpu"]
    ours = {n: best(runs) for n, runs in ours_runs.items()}
    print(
        f"\n### Throughput: {args.substeps} substeps per timing, best of {args.repeats} after a "
        f"warm-up, {args.rounds} interleaved round(s)"
    )
    print_table(warp, ours, args.threads)
    if "cuda" not in warp:
        print("\n(no CUDA: CPU only)")
    print(f"\n({time.perf_counter() - start:.0f} s)")
    if not ok:
        raise SystemExit(
            f"bench_vs_warp.py: positions differ by {check['numba_vs_warp']:.2e} m > {TOLERANCE} m"
        )


if __name__ == "__main__":
    main()
