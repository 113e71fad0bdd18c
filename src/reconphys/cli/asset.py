"""Asset commands: ``make-asset``, ``inspect`` and ``export`` (docs/usage.md)."""

from __future__ import annotations

import json
from pathlib import Path

import typer

from ..errors import InputError
from ..io import check_new_output
from ..names import EXPORT_FORMATS
from ._common import (
    check_non_negative,
    check_positive,
    user_errors,
)

app = typer.Typer()

GROUND_TOLERANCE = 1e-3  # metres a kept pose may reach below the ground (z = 0): rounding only


def _make_gaussians(shape, mesh, ply, num_gaussians, seed, size, keep_pose=False):
    from ..assets.mesh import mesh_to_gaussians
    from ..assets.normalize import normalize_gaussians
    from ..assets.ply import read_ply
    from ..assets.procedural import make_procedural_gaussians

    sources = [s for s in (shape, mesh, ply) if s is not None]
    if len(sources) != 1:
        raise InputError("give exactly one of --shape, --mesh or --ply", field="source")
    if shape is not None:
        if keep_pose:
            raise InputError("a procedural shape has no pose of its own: give --mesh or --ply",
                             field="--keep-pose")  # fmt: skip
        return make_procedural_gaussians(shape, num_gaussians, seed=seed, size=size)
    if mesh is not None:
        return mesh_to_gaussians(mesh, num_gaussians, seed=seed, size=None if keep_pose else size)
    gaussians = read_ply(ply)
    return gaussians if keep_pose else normalize_gaussians(gaussians, size)


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
    keep_pose: bool = typer.Option(
        False,
        "--keep-pose",
        help="Keep the mesh or PLY exactly where it is (world frame, metres, z up, ground z = 0; "
        "e.g. the first frame's pose): no centring, scaling, rotation or lifting (--size, "
        "--height and --no-rotate do not apply).",
    ),
    object_id: str = typer.Option(None, help="Identifier that seeds the anchors (default: name)."),
    overwrite: bool = typer.Option(False, help="Replace an existing asset folder."),
):
    """Build an asset folder from a procedural shape, a mesh or a Gaussian PLY."""
    from ..assets.asset import PhysicsSettings, write_asset
    from ..assets.build import build_asset, place_for_drop
    from ..assets.procedural import SHAPES

    if list_shapes:
        typer.echo(" ".join(SHAPES))
        return
    for name, value in (("--size", size), ("--mass", mass)):
        check_positive(value, name)
    for name, value in (("--stiffness", stiffness), ("--damping", damping)):
        check_non_negative(value, name)
    check_non_negative(friction, "--friction")
    if not 0 <= restitution <= 1:
        raise InputError(f"must be in [0, 1], got {restitution}", field="--restitution")
    check_new_output(out, overwrite)
    gaussians = _make_gaussians(shape, mesh, ply, num_gaussians, seed, size, keep_pose)
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
    if keep_pose:
        lowest = float(gaussians.means[:, 2].min())
        if lowest < -GROUND_TOLERANCE:
            source = str(mesh or ply)
            raise InputError(f"its lowest point is {-lowest:.3f} m below the ground (z = 0): "
                             "give it in world coordinates, z up", source=source)  # fmt: skip
        asset = build_asset(gaussians, physics, linear_velocity, angular_velocity)
    else:
        asset = place_for_drop(
            gaussians, height, seed, physics, linear_velocity, angular_velocity, not no_rotate
        )
    write_asset(asset, out, overwrite=overwrite)
    typer.echo(
        f"wrote {out}: {asset.gaussians.num_gaussians} Gaussians, {asset.num_anchors} anchors, "
        f"{asset.springs.shape[0]} springs, total mass {asset.total_mass():.1f} kg"
    )


@app.command()
@user_errors
def inspect(asset_dir: Path = typer.Argument(..., help="Asset folder.")):
    """Validate an asset folder and print its physical summary as JSON."""
    from ..assets.asset import derived_figures, read_asset
    from ..physics import stable_substeps

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
    from ..assets.asset import read_asset
    from ..assets.export import export_asset

    if fmt not in EXPORT_FORMATS:
        raise InputError(
            f"expected one of {', '.join(EXPORT_FORMATS)}, got {fmt!r}", field="--format"
        )
    check_new_output(out, overwrite)
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
