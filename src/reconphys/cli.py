"""Command line: ``reconphys demo | make-asset | simulate | inspect | make-data | data | train``.

User errors (missing or corrupt files, bad shapes, NaN, unstable attributes) print one line,
``error: <input>: <what is wrong>``, and exit with status 2; no partial output is left behind.
"""

from __future__ import annotations

import functools
import json
import math
import os
import shutil
import sys
import time
from pathlib import Path

import torch
import typer

from . import __version__
from .errors import InputError

app = typer.Typer(
    add_completion=False,
    no_args_is_help=True,
    pretty_exceptions_enable=False,
    help="Build and simulate simulation-ready assets (3D Gaussians + spring-mass physics).",
)


def _version(value: bool):
    if value:
        typer.echo(f"reconphys {__version__}")
        raise typer.Exit()


@app.callback()
def _main(
    version: bool = typer.Option(
        False, "--version", callback=_version, is_eager=True, help="Print the version and exit."
    ),
):
    """reconphys: one video of a dropped object → a simulation-ready asset."""
    # Settling objects drive velocities into float32 denormals, which are very slow on CPUs.
    torch.set_flush_denormal(True)


def user_errors(fn):
    """Turn InputError (and unreadable-input OSErrors) into one line on stderr and exit code 2."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        try:
            return fn(*args, **kwargs)
        except InputError as e:
            typer.echo(f"error: {e}", err=True)
            raise typer.Exit(2) from None

    return wrapper


def _check_positive(value: float, name: str) -> None:
    if not (math.isfinite(value) and value > 0):
        raise InputError(f"must be a positive number, got {value}", field=name)


def _check_non_negative(value: float, name: str) -> None:
    if not (math.isfinite(value) and value >= 0):
        raise InputError(f"must be a finite number ≥ 0, got {value}", field=name)


def _make_gaussians(shape, mesh, ply, num_gaussians, seed, size):
    from .assets.mesh import mesh_to_gaussians
    from .assets.normalize import normalize_gaussians
    from .assets.ply import read_ply
    from .assets.procedural import make_procedural_gaussians

    sources = [s for s in (shape, mesh, ply) if s is not None]
    if len(sources) != 1:
        raise InputError("give exactly one of --shape, --mesh or --ply", field="source")
    if shape is not None:
        return make_procedural_gaussians(shape, num_gaussians, seed=seed, size=size)
    if mesh is not None:
        return mesh_to_gaussians(mesh, num_gaussians, seed=seed, size=size)
    return normalize_gaussians(read_ply(ply), size)


def _random_rotation(seed: int) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    q, r = torch.linalg.qr(torch.randn(3, 3, generator=g, dtype=torch.float64))
    q = q * torch.sign(torch.diagonal(r))
    if torch.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return q.float()


def build_drop_asset(
    gaussians,
    height: float,
    seed: int,
    physics,
    linear_velocity=(0.0, 0.0, 0.0),
    angular_velocity=(0.0, 0.0, 0.0),
    rotate: bool = True,
):
    """Orient the object (random rotation from ``seed``), lift its lowest point to ``height``
    metres and build the asset."""
    from .assets.build import build_asset
    from .assets.normalize import place_on_ground, rotate_gaussians

    if rotate:
        gaussians = rotate_gaussians(gaussians, _random_rotation(seed))
    gaussians = place_on_ground(gaussians, height)
    return build_asset(gaussians, physics, linear_velocity, angular_velocity)


@app.command("make-asset")
@user_errors
def make_asset(
    out: Path = typer.Argument(..., help="Asset folder to write."),
    shape: str = typer.Option(None, help="Built-in procedural shape (see --list-shapes)."),
    mesh: Path = typer.Option(None, help="Mesh file (.obj/.glb/.ply/.stl) to turn into Gaussians."),
    ply: Path = typer.Option(None, help="3DGS Gaussian PLY to use as the appearance."),
    list_shapes: bool = typer.Option(False, "--list-shapes", help="Print the shapes and exit."),
    size: float = typer.Option(0.5, help="Largest bounding-box side, metres."),
    height: float = typer.Option(0.3, help="Height of the lowest point above the ground, metres."),
    mass: float = typer.Option(1.0, help="Mass per anchor, kg."),
    stiffness: float = typer.Option(300.0, help="k, N per unit strain (spring constant k/l N/m)."),
    damping: float = typer.Option(1.0, help="d, N·s per unit strain rate (dashpot d/l N·s/m)."),
    friction: float = typer.Option(0.5, help="Coulomb friction coefficient with the ground."),
    restitution: float = typer.Option(0.0, help="Ground restitution e in [0, 1]."),
    num_gaussians: int = typer.Option(20000, help="Gaussians for --shape / --mesh."),
    num_anchors: int = typer.Option(2048, help="Anchors N_A filling the volume."),
    neighbors: int = typer.Option(32, help="K nearest neighbours that make the springs."),
    min_substeps: int = typer.Option(100, help="Minimum substeps per 0.03 s frame."),
    linear_velocity: tuple[float, float, float] = typer.Option((0.0, 0.0, 0.0), help="m/s"),
    angular_velocity: tuple[float, float, float] = typer.Option((0.0, 0.0, 0.0), help="rad/s"),
    seed: int = typer.Option(0, help="Seed for sampling and the random orientation."),
    no_rotate: bool = typer.Option(False, "--no-rotate", help="Keep the object's orientation."),
    object_id: str = typer.Option(None, help="Identifier that seeds the anchors (default: name)."),
    overwrite: bool = typer.Option(False, help="Replace an existing asset folder."),
):
    """Build an asset folder from a procedural shape, a mesh or a Gaussian PLY."""
    from .assets.asset import PhysicsSettings, write_asset
    from .assets.procedural import SHAPES

    if list_shapes:
        typer.echo(" ".join(SHAPES))
        return
    for name, value in (("--size", size), ("--mass", mass)):
        _check_positive(value, name)
    for name, value in (("--stiffness", stiffness), ("--damping", damping)):
        _check_non_negative(value, name)
    _check_non_negative(friction, "--friction")
    if not 0 <= restitution <= 1:
        raise InputError(f"must be in [0, 1], got {restitution}", field="--restitution")
    if out.exists() and not overwrite:
        raise InputError("already exists (use --overwrite to replace it)", source=str(out))
    gaussians = _make_gaussians(shape, mesh, ply, num_gaussians, seed, size)
    physics = PhysicsSettings(
        mass=mass,
        stiffness=stiffness,
        damping=damping,
        friction=friction,
        restitution=restitution,
        substeps=min_substeps,
        num_anchors=num_anchors,
        num_neighbors=neighbors,
        object_id=object_id or (shape or Path(mesh or ply).stem),
    )
    asset = build_drop_asset(
        gaussians, height, seed, physics, linear_velocity, angular_velocity, not no_rotate
    )
    write_asset(asset, out, overwrite=overwrite)
    typer.echo(
        f"wrote {out}: {asset.gaussians.num_gaussians} Gaussians, {asset.num_anchors} anchors, "
        f"{asset.springs.shape[0]} springs, total mass {asset.total_mass():.1f} kg"
    )


@app.command()
@user_errors
def simulate(
    asset_dir: Path = typer.Argument(..., help="Asset folder (physics.json, anchors.npz, ...)."),
    frames: int = typer.Option(
        None,
        "--frames",
        help="Frames to simulate (frame_dt each; default 30). With --script: the total, free "
        "after the script (default: the script's own length).",
    ),
    out: Path = typer.Option(..., "--out", help="Output folder for trajectory.npz and the mp4."),
    no_render: bool = typer.Option(False, "--no-render", help="Skip rendering the mp4."),
    device: str = typer.Option("auto", help="auto, cpu or cuda."),
    resolution: int = typer.Option(256, help="Video width and height, pixels."),
    view: int = typer.Option(0, help="Dataset view 0–3 (azimuth 0°, 90°, 180°, 270°)."),
    backend: str = typer.Option("auto", help="Renderer: auto, torch or gsplat."),
    save_gaussians: bool = typer.Option(False, help="Also store Gaussian centres per frame."),
    script: Path = typer.Option(
        None, "--script", help="JSON controller script (grab, move, release, ...; docs/viewer.md)."
    ),
    push: str = typer.Option(
        None,
        "--push",
        help='"X,Y,Z" metres: at frame N/3 grab the side facing away from the push, move it by '
        "X,Y,Z over 10 frames, release (docs/viewer.md).",
    ),
):
    """Simulate an asset: writes OUT/trajectory.npz (anchors [T+1, N_A, 3], substeps_used) and,
    unless --no-render, OUT/simulation.mp4 and OUT/preview.png from a dataset view. --script or
    --push drive it with the viewer's controller (grips) and add OUT/interaction.json."""
    from .assets.asset import read_asset
    from .devices import resolve_device
    from .interact.script import load_script, parse_vector, push_script
    from .simulate import simulate_to_folder

    if frames is not None and frames < 1:
        raise InputError(f"must be ≥ 1, got {frames}", field="--frames")
    if resolution < 8:
        raise InputError(f"must be ≥ 8 pixels, got {resolution}", field="--resolution")
    if backend not in ("auto", "torch", "gsplat"):
        raise InputError(f"expected auto, torch or gsplat, got {backend!r}", field="--backend")
    if script is not None and push is not None:
        raise InputError("give --script or --push, not both", field="--push")
    steps = None
    if script is not None:
        steps = load_script(script)
    elif push is not None:
        frames = 30 if frames is None else frames
        steps = push_script(frames, parse_vector(push, "--push"))
    elif frames is None:
        frames = 30
    torch_device = resolve_device(device)
    asset = read_asset(asset_dir)
    try:
        summary = simulate_to_folder(
            asset,
            out,
            frames,
            not no_render,
            torch_device,
            resolution,
            view,
            backend,
            save_gaussians,
            steps,
        )
    except InputError as e:
        raise InputError(str(e), source=str(asset_dir)) from None
    typer.echo(json.dumps(summary))


@app.command()
@user_errors
def inspect(asset_dir: Path = typer.Argument(..., help="Asset folder.")):
    """Validate an asset folder and print its physical summary as JSON."""
    from .assets.asset import derived_figures, read_asset
    from .physics import stable_substeps

    asset = read_asset(asset_dir)
    p = asset.physics
    report = {k: v for k, v in vars(p).items()}
    report["gravity"] = list(p.gravity)
    report.update(derived_figures(asset))
    bound = stable_substeps(asset.model(), asset.initial_state().x, p.frame_dt, 1)
    report["substeps_for_stability"] = bound
    report["substeps_used"] = max(bound, p.substeps)
    typer.echo(json.dumps(report, indent=2))


@app.command()
@user_errors
def export(
    asset_dir: Path = typer.Argument(..., help="Asset folder."),
    fmt: str = typer.Option(
        ..., "--format", help="newton (.npz for NVIDIA Warp / Newton) or mjcf (MuJoCo XML)."
    ),
    out: Path = typer.Option(..., "--out", help="File to write."),
    overwrite: bool = typer.Option(False, help="Replace an existing file."),
):
    """Export an asset to another simulator (docs/export.md): newton writes particles and
    springs (SI, ke = k/l, kd = d/l per spring) and the Gaussian binding to one .npz; mjcf
    writes a MuJoCo flex (anchors as vertices, springs as edges) on a ground plane."""
    from .assets.asset import read_asset
    from .assets.export import FORMATS, export_asset

    if fmt not in FORMATS:
        raise InputError(f"expected one of {', '.join(FORMATS)}, got {fmt!r}", field="--format")
    if out.exists() and not overwrite:
        raise InputError("already exists (use --overwrite to replace it)", source=str(out))
    asset = read_asset(asset_dir)
    path = export_asset(asset, out, fmt)
    typer.echo(
        json.dumps(
            {
                "format": fmt,
                "out": str(path),
                "anchors": asset.num_anchors,
                "springs": int(asset.springs.shape[0]),
                "bytes": path.stat().st_size,
            }
        )
    )


@app.command()
@user_errors
def demo(
    out: Path = typer.Option(Path("demo_out"), help="Output folder."),
    shape: str = typer.Option("bunny", help="Procedural shape."),
    frames: int = typer.Option(50, help="Frames to simulate (0.03 s each)."),
    resolution: int = typer.Option(256, help="Video size, pixels."),
    num_gaussians: int = typer.Option(12000, help="Gaussians of the object."),
    num_anchors: int = typer.Option(2048, help="Anchors N_A."),
    device: str = typer.Option("auto", help="auto, cpu or cuda."),
    seed: int = typer.Option(0, help="Seed for the shape and orientation."),
):
    """Build a procedural object, drop it, and write OUT/asset, OUT/trajectory.npz and an mp4."""
    from .assets.asset import PhysicsSettings, read_asset, write_asset
    from .assets.procedural import make_procedural_gaussians
    from .devices import resolve_device
    from .simulate import simulate_to_folder

    torch_device = resolve_device(device)
    started = time.perf_counter()
    gaussians = make_procedural_gaussians(shape, num_gaussians, seed=seed)
    physics = PhysicsSettings(
        mass=1.0,
        stiffness=250.0,
        damping=1.0,
        friction=0.6,
        num_anchors=num_anchors,
        object_id=f"demo-{shape}-{seed}",
    )
    asset = build_drop_asset(gaussians, 0.35, seed, physics, angular_velocity=(1.5, -2.0, 0.5))
    asset_dir = out / "asset"
    if asset_dir.exists():
        shutil.rmtree(asset_dir)
    write_asset(asset, asset_dir)
    typer.echo(
        f"asset: {asset_dir} ({asset.gaussians.num_gaussians} Gaussians, {asset.num_anchors} "
        f"anchors, {asset.springs.shape[0]} springs) in {time.perf_counter() - started:.1f} s"
    )
    asset = read_asset(asset_dir)  # simulate what was written: the file format is the contract
    summary = simulate_to_folder(
        asset, out, frames, True, torch_device, resolution, 0, "auto", False
    )
    typer.echo(json.dumps(summary))
    typer.echo(f"video: {out / 'simulation.mp4'}   preview: {out / 'preview.png'}")


# ----------------------------------------------------------------------------------------------
# synthetic dataset (docs/dataset.md)

data_app = typer.Typer(
    no_args_is_help=True, help="Inspect, merge and export synthetic datasets (see make-data)."
)
app.add_typer(data_app, name="data")

NAMED_SOURCES = ("procedural", "pybullet", "objaverse")


@app.command("make-data")
@user_errors
def make_data(
    out: Path = typer.Option(..., "--out", help="Dataset folder (created; resumed if it exists)."),
    source: str = typer.Option(
        "procedural", help="procedural, pybullet, objaverse, or a folder of .obj/.glb/.ply files."
    ),
    preset: str = typer.Option("small", help="small (CPU-sized) or paper (450×10 + 46×2, 512²)."),
    objects: int = typer.Option(None, help="Training objects."),
    test_objects: int = typer.Option(None, help="Held-out test objects (split by object)."),
    samples_per_object: int = typer.Option(None, help="Attribute samples per training object."),
    test_samples_per_object: int = typer.Option(None, help="Attribute samples per test object."),
    resolution: int = typer.Option(None, help="Image width and height, pixels."),
    frames: int = typer.Option(None, help="Frames per video (frame 0 = initial state)."),
    num_gaussians: int = typer.Option(None, help="Gaussians per object."),
    num_anchors: int = typer.Option(None, help="Anchors N_A per object."),
    neighbors: int = typer.Option(None, help="K nearest neighbours that make the springs."),
    min_substeps: int = typer.Option(None, help="Minimum substeps per frame."),
    distribution: str = typer.Option(None, help="Of m, k, d: uniform (paper) or log-uniform."),
    max_horizontal_speed: float = typer.Option(
        None, help="Initial horizontal speed bound per axis, m/s (default 0.3)."
    ),
    max_angular_speed: float = typer.Option(None, help="Initial spin bound, rad/s (default 2.0)."),
    seed: int = typer.Option(0, help="Dataset seed: object selection, splits, all samples."),
    workers: int = typer.Option(
        0, help="Worker processes (0: one per CPU core, one with --device cuda)."
    ),
    device: str = typer.Option("auto", help="auto, cpu or cuda (simulation and rendering)."),
    shard: str = typer.Option(None, help="I/N: make only shard I of N (then: data merge)."),
    objaverse_root: Path = typer.Option(None, help="Objaverse mirror (hf-objaverse-v1 folder)."),
    objaverse_uids: Path = typer.Option(None, help="File of Objaverse UIDs to draw from."),
    download: bool = typer.Option(False, help="Objaverse only: fetch missing objects (network)."),
):
    """Generate a synthetic drop-video dataset: objects × attribute samples, 30 frames, 4 views.

    Writes OUT/objects/ (canonical Gaussians + anchors, once per object), OUT/samples/ (frames,
    trajectory, cameras, attributes, mp4 per view) and OUT/manifest.json. Rerunning the same
    command resumes a killed run; a run with other settings into the same OUT is refused."""
    from .data.make import make_dataset
    from .data.plan import parse_shard
    from .data.settings import make_settings

    if source not in NAMED_SOURCES:
        source = str(Path(source).resolve())
    settings = make_settings(
        preset,
        source=source,
        seed=seed,
        objects=objects,
        test_objects=test_objects,
        samples_per_object=samples_per_object,
        test_samples_per_object=test_samples_per_object,
        resolution=resolution,
        num_frames=frames,
        num_gaussians=num_gaussians,
        num_anchors=num_anchors,
        num_neighbors=neighbors,
        min_substeps=min_substeps,
        distribution=distribution,
        max_horizontal_speed=max_horizontal_speed,
        max_angular_speed=max_angular_speed,
        objaverse_uids=str(objaverse_uids.resolve()) if objaverse_uids else None,
    )
    report = make_dataset(
        settings,
        out,
        workers=workers,
        device=device,
        shard=parse_shard(shard),
        objaverse_root=objaverse_root,
        download=download,
        progress=True,
    )
    manifest = report.manifest
    name = "manifest.json" if shard is None else f"its shard manifest ({shard})"
    typer.echo(
        f"wrote {report.generated} samples ({report.skipped} were already there) in "
        f"{report.seconds:.1f} s: {out}, {len(manifest['samples'])} samples listed in {name}"
    )


@data_app.command("show")
@user_errors
def data_show(
    root: Path = typer.Argument(..., help="Dataset folder."),
    sheet: Path = typer.Option(None, help="Contact-sheet PNG (default: ROOT/contact_sheet.png)."),
    samples: int = typer.Option(4, help="Samples (rows) in the contact sheet."),
    view: int = typer.Option(0, help="View 0–3 shown in the contact sheet."),
):
    """Print a summary table (splits, attribute ranges, contact-frame histogram) and write a
    contact sheet (rows: samples; columns: evenly spaced frames of one view)."""
    import imageio.v2 as imageio

    from .data.show import contact_sheet, summary

    if not 0 <= view < 4:
        raise InputError(f"expected 0, 1, 2 or 3, got {view}", field="--view")
    typer.echo(summary(root))
    sheet = sheet or root / "contact_sheet.png"
    try:
        imageio.imwrite(sheet, contact_sheet(root, samples, view), format="PNG")
    except OSError as e:
        raise InputError(f"cannot write ({e.strerror or e})", source=str(sheet)) from None
    typer.echo(f"contact sheet: {sheet}")


@data_app.command("merge")
@user_errors
def data_merge(
    out: Path = typer.Argument(..., help="Dataset folder that receives manifest.json."),
    shards: list[Path] = typer.Argument(None, help="Other folders holding shards (copied in)."),
):
    """Check the shard manifests (make-data --shard I/N) and join them into OUT/manifest.json."""
    from .data.make import merge_shards

    merged = merge_shards(out, shards or [])
    typer.echo(f"merged {len(merged['samples'])} samples into {out / 'manifest.json'}")


@data_app.command("export")
@user_errors
def data_export(
    root: Path = typer.Argument(..., help="Dataset folder."),
    sample: str = typer.Argument(..., help="Sample id (see manifest.json)."),
    out: Path = typer.Argument(..., help="Asset folder to write."),
    overwrite: bool = typer.Option(False, help="Replace an existing asset folder."),
):
    """Write one sample as an asset folder (placed object, attributes, initial velocity): what
    `reconphys simulate --frames FRAMES-1` turns into the sample's stored trajectory."""
    from .assets.asset import write_asset
    from .data.dataset import DropDataset

    dataset = DropDataset(root, allow_incomplete=True, verify=False)
    write_asset(dataset.asset(dataset.index_of(sample)), out, overwrite=overwrite)
    typer.echo(f"wrote {out}")


# ----------------------------------------------------------------------------------------------
# interactive viewer (docs/viewer.md)


@app.command()
@user_errors
def view(
    asset_dir: Path = typer.Argument(..., help="Asset folder to manipulate."),
    port: int = typer.Option(8080, help="Port of the web viewer."),
    host: str = typer.Option("127.0.0.1", help="Interface to listen on (0.0.0.0: all)."),
    device: str = typer.Option("auto", help="Simulation device: auto, cpu or cuda."),
    substeps: int = typer.Option(None, help="Substeps per frame (never below stability)."),
    paused: bool = typer.Option(False, "--paused", help="Start paused."),
    record_dir: Path = typer.Option(Path("recordings"), help="Where recordings are saved."),
    script: Path = typer.Option(None, help="Run this JSON action script headless instead."),
    out: Path = typer.Option(None, help="Output folder of --script (trajectory, mp4)."),
    resolution: int = typer.Option(256, help="Video size of --script, pixels."),
    benchmark: int = typer.Option(0, help="Time this many frames headless, print, exit."),
):
    """Open ASSET in a browser viewer: live simulation; drop, grab, squeeze and stretch it
    (needs the `viewer` extra). With --script: the same controls, headless, from a file."""
    from .assets.asset import read_asset
    from .devices import resolve_device
    from .viewer.command import view_command

    if not 0 <= port < 65536:
        raise InputError(f"must be a port number 0–65535, got {port}", field="--port")
    if resolution < 8:
        raise InputError(f"must be ≥ 8 pixels, got {resolution}", field="--resolution")
    if substeps is not None and substeps < 1:
        raise InputError(f"must be ≥ 1, got {substeps}", field="--substeps")
    torch_device = resolve_device(device)
    asset = read_asset(asset_dir)
    view_command(
        asset, torch_device, host, port, substeps, paused, record_dir, script, out, resolution,
        benchmark, echo=typer.echo,
    )  # fmt: skip


# ----------------------------------------------------------------------------------------------
# evaluation (docs/evaluation.md)


@app.command("evaluate")
@user_errors
def evaluate(
    data: Path = typer.Option(..., "--data", help="Dataset folder written by make-data."),
    out: Path = typer.Option(..., "--out", help="Report folder to write."),
    split: str = typer.Option("test", help="test, train or all."),
    methods: str = typer.Option(
        "trivial,oracle,springgaus,appearance", help="Comma-separated methods to compare."
    ),
    limit: int = typer.Option(None, help="Evaluate only the first N samples of the split."),
    budget_seconds: float = typer.Option(
        60.0, help="Seconds per scene for the per-scene fits (springgaus, appearance)."
    ),
    device: str = typer.Option("cpu", help="auto, cpu or cuda (fits, simulation, rendering)."),
    seed: int = typer.Option(0, help="Seed of the per-scene fits."),
    chamfer_points: int = typer.Option(8192, help="Points per set for the Chamfer distance."),
    emd_points: int = typer.Option(2048, help="Points per set for the EMD (exact matching)."),
    sheet_samples: int = typer.Option(2, help="Samples shown in the contact sheet."),
    threads: int = typer.Option(0, help="torch CPU threads (0: torch's default)."),
    model: Path = typer.Option(
        None,
        help="Trained predictor of the reconphys method: a .safetensors file or a `reconphys "
        "train` output folder (default: $RECONPHYS_MODEL, else the shipped model).",
    ),
    overwrite: bool = typer.Option(False, help="Replace an existing report folder."),
):
    """Compare methods on a split of a dataset: the paper's Tables 1–3 with the trivial control.

    Writes OUT/metrics.json, OUT/report.md, OUT/summary.csv, OUT/per_sample.csv,
    OUT/per_frame.csv and figures (PSNR per frame, attribute scatter, contact sheet)."""
    from .devices import resolve_device
    from .eval.evaluate import EvalSettings, run_evaluation
    from .eval.methods import parse_methods
    from .eval.report import check_output, write_report
    from .eval.samples import EvalSet

    names = parse_methods(methods)
    _check_positive(budget_seconds, "--budget-seconds")
    for value, flag in ((chamfer_points, "--chamfer-points"), (emd_points, "--emd-points")):
        if value < 1:
            raise InputError(f"must be ≥ 1, got {value}", field=flag)
    if sheet_samples < 0 or threads < 0:
        flag = "--sheet-samples" if sheet_samples < 0 else "--threads"
        raise InputError("must be ≥ 0", field=flag)
    if model is not None and not {"reconphys", "reconphys_ff"} & set(names):
        raise InputError("only the reconphys methods use a model; add one to --methods", "--model")
    torch_device = resolve_device(device)
    check_output(out, overwrite)
    eval_set = EvalSet(data, split, limit)
    if threads:
        from .threads import set_cpu_threads

        set_cpu_threads(threads)
    settings = EvalSettings(
        methods=tuple(names),
        budget_seconds=budget_seconds,
        device=str(torch_device),
        seed=seed,
        chamfer_points=chamfer_points,
        emd_points=emd_points,
        sheet_samples=sheet_samples,
        model=None if model is None else str(model),
    )
    optional = {
        "--limit": (limit, None),
        "--device": (device, "cpu"),
        "--seed": (seed, 0),
        "--chamfer-points": (chamfer_points, 8192),
        "--emd-points": (emd_points, 2048),
        "--threads": (threads, 0),
        "--model": (model, None),
    }
    command = (
        f"reconphys evaluate --data {data} --split {split} --methods {','.join(names)} "
        f"--budget-seconds {budget_seconds:g}"
        + "".join(
            f" {flag} {value}" for flag, (value, default) in optional.items() if value != default
        )
        + f" --out {out}"
    )
    typer.echo(f"evaluating {len(eval_set)} {split} samples with {', '.join(names)}")
    results = run_evaluation(eval_set, settings, log=typer.echo)
    document = write_report(
        results, out, str(data), split, limit, eval_set.settings, command, overwrite
    )
    for name, entry in document["methods"].items():
        recon, future = entry["reconstruction"]["psnr"], entry["future"]["psnr"]
        typer.echo(
            f"{name:<20} PSNR reconstruction "
            + ("–" if recon is None else f"{recon:.2f}")
            + " dB, future "
            + ("–" if future is None else f"{future:.2f}")
            + " dB"
        )
    typer.echo(f"report: {out / 'report.md'} ({results.seconds:.0f} s)")


# ----------------------------------------------------------------------------------------------
# training (docs/training.md)


@app.command("train")
@user_errors
def train(
    config: Path = typer.Argument(..., help="Config file (.toml or .json): see configs/."),
    overrides: list[str] = typer.Argument(
        None, help="KEY=VALUE overrides with dotted keys, e.g. optim.lr=3e-4 train.steps=200."
    ),
    overwrite: bool = typer.Option(
        False, help="Start again: remove OUT's checkpoint, logs and model instead of resuming."
    ),
    progress: bool = typer.Option(True, help="Show a progress bar (else a line per log_every)."),
):
    """Train the physics predictor: self-supervised (photometric loss through simulator and
    renderer), supervised or mixed. Resumes from OUT/checkpoint.pt when there is one; runs
    under torchrun for DDP. Writes OUT/log.jsonl, OUT/checkpoint.pt, OUT/model.safetensors and
    OUT/model.json (OUT = train.out)."""
    from .train.config import load_config
    from .train.trainer import train as run_training

    settings = load_config(config, overrides or [])
    result = run_training(settings, overwrite=overwrite, progress=progress, log=typer.echo)
    if int(os.environ.get("RANK", "0")) != 0:
        return  # under torchrun: rank 0 reports
    if result.records or result.first_step == 1:
        last = result.records[-1] if result.records else {}
        typer.echo(
            f"trained {result.step} steps ({result.seconds:.0f} s in total), final loss "
            f"{last.get('loss', float('nan')):.5g}: {result.out / 'model.safetensors'}"
        )
    else:
        typer.echo(f"{result.out} already has {result.step} steps (train.steps); nothing to do")


# The user-path commands (predict, data video) live in their own module.
from .cli_predict import data_video, predict_command, train_gs_command  # noqa: E402

app.command("predict")(user_errors(predict_command))
app.command("train-gs")(user_errors(train_gs_command))
data_app.command("video")(user_errors(data_video))


def main() -> None:
    try:
        app()
    except KeyboardInterrupt:
        typer.echo("interrupted", err=True)
        sys.exit(130)


if __name__ == "__main__":
    main()
