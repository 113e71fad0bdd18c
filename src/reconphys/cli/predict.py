"""``reconphys predict``: one recording of a dropped object → an asset (docs/usage.md)."""

from __future__ import annotations

import math
from pathlib import Path

import typer

from ..errors import InputError
from ..io import check_new_output
from ._common import DEVICE_CHOICES, user_errors

app = typer.Typer()

TIMING_ORDER = (
    "model_load",
    "decode",
    "gaussians",
    "physics_network",
    "asset_build",
    "search",
    "refine",
    "write",
    "preview",
)


@app.command("predict")
@user_errors
def predict_command(
    input: Path = typer.Argument(
        ..., help="Video file (mp4/mov/gif/...), folder of frames, or a dataset folder (--sample)."
    ),
    out: Path = typer.Option(
        ..., "--out", help="Asset folder to write (docs/assets.md + preview)."
    ),
    gaussians: Path = typer.Option(
        None, help="Gaussian PLY of the object (default: predicted from frame 0)."
    ),
    mesh: Path = typer.Option(
        None,
        help="Instead of --gaussians: the object's mesh (.obj/.glb/.stl/...) in frame 0's pose, "
        "in the camera file's world frame, metres.",
    ),
    masks: Path = typer.Option(None, help="Folder of object masks, one image per frame."),
    background: Path = typer.Option(None, help="Clean plate image for background subtraction."),
    camera: Path = typer.Option(
        None,
        help="Camera JSON (K, world_to_cam, ground_height; K alone: the pose read from the "
        "video), or 'dataset' (the dataset's view 0); "
        "default: estimated from the video (scale from the free fall, ground where it first "
        "touches, or else where it rests; needs ≥ 4 frames of fall).",
    ),
    fov: float = typer.Option(
        None,
        help="Vertical field of view, degrees, for the estimated camera (default: the phone's "
        "lens from the video's metadata, else 45° across the shorter side).",
    ),
    touch: str = typer.Option(
        None,
        help="How the object meets the ground, for the camera read from the video: 'soft' (the "
        "default: it squashes as it lands) or 'rigid' (it stops or bounces at once: a hard toy, "
        "a block). 'soft' reads a rigid object's ground ~7 cm high.",
    ),
    drop_height: float = typer.Option(
        None,
        help="Metres from the ground up to the object's lowest point at the release (frame 0), "
        "if you measured it: the ground is put there instead of read from the video (the "
        "video's read is kept beside it in prediction.json, with a warning where they part). "
        "Not with a camera file that has a pose.",
    ),
    fps: float = typer.Option(None, help="Frame rate of a frame folder (or to override)."),
    start: str = typer.Option(
        "0",
        help="Seconds into the recording where the object is released (frame 0), or 'auto': "
        "read from the masks (the object held still, then falling from rest; such a hold "
        "is read as let go at rest, whatever a hand does to the first frames' masks). A hold "
        "shown before a start given is read too: the velocity is then that of a fall from rest "
        "at the release read (within 3 frames of the start).",
    ),
    end: float = typer.Option(
        None,
        help="Seconds into the recording to stop reading at (default: 0.87 s after the start, "
        "30 frames, as long as the training clips; the rest is not decoded).",
    ),
    sample: str = typer.Option(None, help="Dataset input: the sample id."),
    view: int = typer.Option(None, help="Dataset input: the view (default: the model's)."),
    model: Path = typer.Option(None, help="Physics predictor (default: the shipped model)."),
    geometry: str = typer.Option(
        "auto",
        help="auto (--gaussians, else a dataset's true Gaussians, else the 3DGS predictor) or "
        "predicted (the 3DGS predictor even for a dataset sample).",
    ),
    gs_model: Path = typer.Option(
        None, help="3DGS predictor (default: the shipped one for the recording's look)."
    ),
    placement: str = typer.Option(
        "auto",
        help="Given PLY or mesh: auto, as-is or fit (moved onto frame 0's mask); refused when "
        "its silhouette still does not match the mask (IoU < 0.7 on a window around the object).",
    ),
    ground: str = typer.Option(
        "camera", help="Ground plane: camera (its file's ground_height, else 0) or landed."
    ),
    anchors: int = typer.Option(None, help="Anchors N_A (default: the model's training data)."),
    refine: bool = typer.Option(
        True,
        "--refine/--no-refine",
        help="Fit k/m, d/m and friction to the recording by batched re-simulation (seconds), "
        "with a 10–90 % interval each; --no-refine: the feed-forward network alone (< 1 s).",
    ),
    refine_steps: int = typer.Option(
        0, "--refine-steps", help="Gradient refinement steps after that (minutes; 0: none)."
    ),
    refine_resolution: int = typer.Option(64, help="Render size of the refinement, pixels."),
    preview_frames: int = typer.Option(
        60, help="Frames in preview.mp4 (0: no preview; pipeline.settings.PREVIEW_FRAMES)."
    ),
    device: str = typer.Option("auto", help=f"{DEVICE_CHOICES}."),
    overwrite: bool = typer.Option(False, help="Replace an existing OUT."),
):
    """Predict a simulation-ready asset from one recording of a dropped object: OUT gets the
    asset (gaussians.ply, anchors.npz, binding.npz, physics.json), preview.mp4/.png (observed |
    simulated) and prediction.json (attributes, timings, how each input was read)."""
    from ..devices import resolve_device
    from ..pipeline.predict import predict, write_outputs

    check_new_output(out, overwrite)
    if fps is not None and not (math.isfinite(fps) and fps > 0):
        raise InputError(f"must be a positive frame rate, got {fps}", field="--fps")
    if start != "auto":
        try:
            start = float(start)
        except ValueError:
            raise InputError(
                f"expected seconds or 'auto', got {start!r}", field="--start"
            ) from None
        if not (math.isfinite(start) and start >= 0):
            raise InputError(f"must be ≥ 0 seconds, got {start}", field="--start")
    first = 0.0 if start == "auto" else start
    if end is not None and not (math.isfinite(end) and end > first):
        raise InputError(f"must be after --start ({first:g} s), got {end}", field="--end")
    if anchors is not None and anchors < 4:
        raise InputError(f"must be ≥ 4, got {anchors}", field="--anchors")
    if fov is not None and not (math.isfinite(fov) and 1 <= fov <= 170):
        raise InputError(
            f"must be a vertical field of view in [1, 170] degrees, got {fov}", "--fov"
        )
    if preview_frames < 0:
        raise InputError(f"must be ≥ 0, got {preview_frames}", field="--preview-frames")
    torch_device = resolve_device(device)
    result = predict(
        input,
        gaussians=gaussians,
        mesh=mesh,
        masks=masks,
        background=background,
        camera=camera,
        fov=fov,
        touch=touch,
        drop_height=drop_height,
        fps=fps,
        start=start,
        end=end,
        sample=sample,
        view=view,
        model=model,
        geometry=geometry,
        gs_model=gs_model,
        placement=placement,
        ground=ground,
        num_anchors=anchors,
        refine=refine,
        refine_steps=refine_steps,
        refine_resolution=refine_resolution,
        device=torch_device,
        progress=True,
    )
    summary = write_outputs(result, out, overwrite, preview_frames, torch_device)
    attributes = summary["attributes"]
    typer.echo(
        f"wrote {out}: mass {attributes['mass']:.3g} kg/anchor, stiffness "
        f"{attributes['stiffness']:.4g}, damping {attributes['damping']:.3g}, friction "
        f"{attributes['friction']:.2f} ({summary['anchors']} anchors, {summary['gaussians']} "
        f"Gaussians; geometry: {summary['geometry']})"
    )
    read = summary.get("input", {})
    if read.get("start_how", "").startswith("read from the masks"):
        typer.echo(f"release read from the masks at {read['start_s']:.3f} s: frame 0 from there")
    elif "release" in read:  # a start given, the hold before it read (capture/observation.py)
        before = read["start_how"].split("; ", 1)[-1]
        typer.echo(f"--start {read['start_s']:g}: {before}")
    if read.get("dynamic_range"):  # an HDR phone video, read as SDR
        typer.echo(f"colours: {read['dynamic_range']}")
    estimate = read.get("camera_estimate")
    if estimate is not None:
        low, high = estimate["size_factor_10_90"]
        typer.echo(
            f"camera read from the video (vertical fov {estimate['fov_deg']:.1f}°, "
            f"{estimate['fov_from']}): the object's size and speeds are known to "
            f"×{low:.2f}–×{high:.2f} (10–90 %)"
            + ("; give --camera FILE for more" if high > 1.25 else "")
        )
        drop_low, drop_high = estimate["drop_height_m_10_90"]
        if estimate.get("drop_height_given"):  # --drop-height
            read_drop = estimate["drop_height_read_m"]
            typer.echo(
                f"ground from {estimate['ground_from']}; the video reads "
                + ("none (refused)" if read_drop is None else f"{read_drop:.2f} m")
            )
        else:
            typer.echo(
                f"ground read from {estimate['ground_from']}: the object starts "
                f"{estimate['drop_height_m']:.2f} m above it ({drop_low:.2f}–{drop_high:.2f} m, "
                "10–90 %; measured, --drop-height puts it there)"
            )
        if estimate.get("drop_height_warning"):
            typer.echo(f"warning: drop height: {estimate['drop_height_warning']}", err=True)
    masks_warning = read.get("masks_rating", {}).get("warning")
    if masks_warning:
        typer.echo(f"warning: masks: {masks_warning}", err=True)
    distance_warning = summary.get("object_distance", {}).get("warning")
    if distance_warning:
        typer.echo(f"warning: object distance: {distance_warning}", err=True)
    velocity_warning = summary.get("initial_velocity", {}).get("warning")
    if velocity_warning:
        typer.echo(f"warning: initial velocity: {velocity_warning}", err=True)
    if "model_choice" in summary:
        typer.echo(f"physics network: {summary['model']} ({summary['model_choice']})")
    if "gs_model_choice" in summary:
        typer.echo(f"3DGS predictor: {summary['gs_model_choice']}")
    intervals = summary["intervals"]
    s = summary.get("search")
    if intervals:
        with_network = s is None or s.get("network_sigma") is not None
        kept = (
            "  not shown by the recording: the network's belief"
            if with_network
            else "  not shown by the recording: the network's value kept"
        )
        lines = [
            f"  {name:<13} {summary['observables'][name]:7.3f}   [{lo:7.3f}, {hi:7.3f}]"
            + (kept if s is not None and name in s["undetermined"] else "")
            for name, (lo, hi) in intervals.items()
        ]
        if s is None:
            head = "feed-forward (--no-refine): observable, answer, 10–90 % of the network's belief"
        else:
            head = f"search: {s['rollouts']} batched rollouts in {s['seconds']} s: observable, "
            head += (
                "answer, 10–90 % of the recording's fit × the network's belief"
                if with_network
                else "best, 10–90 % interval (a wide one: the video does not show it)"
            )
        head += " (natural logs of the SI ratios)"
        typer.echo(head + ":\n" + "\n".join(lines))
    else:
        typer.echo("no intervals: the feed-forward answer alone (--no-refine), not an ensemble")
    if "refine" in summary:
        r = summary["refine"]
        typer.echo(
            f"refine: {r['steps']} steps in {r['seconds']} s, photometric loss "
            f"{r['loss_initial']:.3g} → {r['loss_best']:.3g} (best at step {r['best_step']})"
        )
    timings = summary["timings_s"]
    parts = [f"{k} {timings[k]:.3f}" for k in TIMING_ORDER if k in timings]
    typer.echo("seconds: " + ", ".join(parts))
