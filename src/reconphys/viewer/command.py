"""What ``reconphys view`` does: serve the browser viewer, run a script headless, or benchmark."""

from __future__ import annotations

import json
import time
from pathlib import Path

import torch

from ..assets.asset import Asset
from ..errors import InputError
from .session import ViewerSession


def measure_frames_per_second(
    session: ViewerSession,
    frames: int,
    warmup: int = 2,
    grip: bool = False,
) -> dict:
    """Simulate ``frames`` frames in the calling thread (after ``warmup`` frames) and report
    simulation frames per wall-clock second. With ``grip``, one grip holds the top of the
    object during the measurement (the viewer's grab path: a control force every substep)."""
    torch.set_flush_denormal(True)
    if grip:
        means = session.gaussian_means()
        session.grab(means[int(torch.argmax(means[:, 2]))], name="benchmark grip")
    session.advance(warmup)
    if session.device.type == "cuda":
        torch.cuda.synchronize(session.device)
    started = time.perf_counter()
    done = session.advance(frames)
    if session.device.type == "cuda":
        torch.cuda.synchronize(session.device)
    seconds = time.perf_counter() - started
    fps = done / seconds
    return {
        "anchors": session.asset.num_anchors,
        "springs": int(session.asset.springs.shape[0]),
        "substeps": session.substeps,
        "stability_bound": session.status().stable_substeps,
        "grip": grip,
        "frames": done,
        "seconds": round(seconds, 3),
        "frames_per_second": round(fps, 2),
        "substeps_per_second": round(fps * session.substeps, 1),
        "realtime_factor": round(fps * session.frame_dt, 3),
        "device": str(session.device),
        "torch_threads": torch.get_num_threads(),
    }


def view_command(
    asset: Asset,
    device: torch.device,
    host: str,
    port: int,
    substeps: int | None,
    paused: bool,
    record_dir: Path,
    script: Path | None,
    out: Path | None,
    resolution: int,
    benchmark: int,
    echo=print,
) -> None:
    """The body of ``reconphys view`` (arguments already checked by the CLI)."""
    session = ViewerSession(asset, device=device)
    if substeps is not None:
        session.set_substeps(substeps)
    if benchmark > 0:
        for grip in (False, True):
            measurement = measure_frames_per_second(session, benchmark, grip=grip)
            echo(json.dumps(measurement))
            session.reset()
        return
    if script is not None:
        from ..interact.recording import write_recording
        from ..interact.script import load_script, run_script

        if out is None:
            raise InputError("--script needs --out (the folder for the results)", field="--out")
        steps = load_script(script)
        started = time.perf_counter()
        recording = run_script(session, steps)
        seconds = time.perf_counter() - started
        paths = write_recording(asset, recording, out, resolution=resolution, device=device)
        status = session.status()
        echo(
            json.dumps(
                {
                    "frames": recording.anchors.shape[0] - 1,
                    "simulate_seconds": round(seconds, 3),
                    "max_speed_m_per_s": round(status.max_speed, 4),
                    "lowest_z_m": round(status.lowest_z, 4),
                    **{kind: str(path) for kind, path in paths.items()},
                }
            )
        )
        return

    from .app import ViewerApp

    app = ViewerApp(session, host=host, port=port, record_dir=record_dir)
    app.start()
    if not paused:
        app.session.play()
    echo(f"viewer: {app.url}  (Ctrl+C to stop)")
    if host in ("127.0.0.1", "localhost"):
        echo(f"from another machine: ssh -L {app.port}:127.0.0.1:{app.port} THIS_HOST, then open")
        echo(f"http://127.0.0.1:{app.port} there (or run with --host 0.0.0.0)")
    try:
        while True:
            time.sleep(1.0)
    finally:
        app.close()
