"""Dataset commands: ``make-data`` and ``data show | merge | export | video`` (docs/dataset.md)."""

from __future__ import annotations

import json
import shutil
from dataclasses import replace
from pathlib import Path

import typer

from ..errors import InputError
from ..io import atomic_folder, check_new_output
from ._common import DEVICE_CHOICES, given_options, user_errors

app = typer.Typer()
data_app = typer.Typer(
    no_args_is_help=True, help="Inspect, merge and export synthetic datasets (see make-data)."
)

NAMED_SOURCES = ("procedural", "pybullet", "objaverse")
# make-data options that set a DataSettings field (option → field); the others say how to run
SETTINGS_OPTIONS = {
    "source": "source",
    "seed": "seed",
    "objects": "objects",
    "test_objects": "test_objects",
    "samples_per_object": "samples_per_object",
    "test_samples_per_object": "test_samples_per_object",
    "resolution": "resolution",
    "frames": "num_frames",
    "num_gaussians": "num_gaussians",
    "num_anchors": "num_anchors",
    "neighbors": "num_neighbors",
    "min_substeps": "min_substeps",
    "distribution": "distribution",
    "max_horizontal_speed": "max_horizontal_speed",
    "max_angular_speed": "max_angular_speed",
    "toss_fraction": "toss_fraction",
    "scene": "scene",
    "objaverse_uids": "objaverse_uids",
    "stretch": "stretch_range",
    "vivid_share": "vivid_share",
    "contrast_share": "contrast_share",
    "hand_share": "hand_share",
    "grey_share": "grey_share",
    "exposure": "exposure_range_s",
    "readout": "readout_range_s",
}


@app.command("make-data")
@user_errors
def make_data(
    ctx: typer.Context,
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
    toss_fraction: float = typer.Option(
        None,
        help="Share of tosses (0.5–1.5 m/s sideways, so friction shows); the rest are drops "
        "(default 0.5; the paper preset: 0, released from rest).",
    ),
    scene: str = typer.Option(
        None,
        help="plain (the object on black, fixed cameras: the default) or realistic (a textured "
        "ground, backdrop, light and contact shadow, a camera per sample, objects 0.1–0.6 m, "
        "sensor noise, H.264 compression; true masks stored as masks.npz).",
    ),
    vivid_share: float = typer.Option(
        None,
        help="Realistic look only: the share of scenes drawn vivid (saturated many-coloured "
        "floors and backdrops, a printed pattern on the object; default 0).",
    ),
    contrast_share: float = typer.Option(
        None,
        help="Realistic look only: the share of scenes whose floor is high-contrast (a dark and "
        "a bright colour in checkers, tiles or blobs, as an engine's default floor; default 0).",
    ),
    hand_share: float = typer.Option(
        None,
        help="Realistic look only: the share of samples released from a hand in view (a palm, "
        "fingers and a forearm holding the object's top, withdrawn or kept still after the "
        "release; the masks are the object's visible pixels; default 0).",
    ),
    grey_share: float = typer.Option(
        None,
        help="Realistic look only: the share of samples whose object is grey (its colours kept "
        "at 0–15 % of their saturation: grey, white or black; default 0).",
    ),
    exposure: float = typer.Option(
        None,
        help="Realistic look only: the longest the shutter stays open, seconds (each sample's "
        "drawn uniformly from 0 to it, at most the frame interval; a phone indoors: 1/30 s): "
        "the object blurred along its motion. Default 0: sharp frames.",
    ),
    readout: float = typer.Option(
        None,
        help="Realistic look only: the longest the sensor takes to read its rows, top to "
        "bottom, seconds (each sample's drawn uniformly from 0 to it, at most the frame "
        "interval; a phone's rolling shutter: 0.01-0.03). Default 0: every row at once.",
    ),
    stretch: float = typer.Option(
        None,
        help="Stretch each mesh along a random axis by up to this factor (log-uniform from 1; "
        "default 1: as the file is), so compact meshes also give long, thin objects.",
    ),
    seed: int = typer.Option(0, help="Dataset seed: object selection, splits, all samples."),
    workers: int = typer.Option(
        0, help="Worker processes (0: one per CPU core, one with --device cuda)."
    ),
    device: str = typer.Option("auto", help=f"{DEVICE_CHOICES} (simulation and rendering)."),
    shard: str = typer.Option(None, help="I/N: make only shard I of N (then: data merge)."),
    objaverse_root: Path = typer.Option(None, help="Objaverse mirror (hf-objaverse-v1 folder)."),
    objaverse_uids: Path = typer.Option(None, help="File of Objaverse UIDs to draw from."),
    download: bool = typer.Option(False, help="Objaverse only: fetch missing objects (network)."),
    config: Path = typer.Option(
        None,
        "--config",
        help="TOML/JSON file of DataSettings fields (e.g. configs/data_small.toml) applied over "
        "--preset; options given here override it.",
    ),
):
    """Generate a synthetic drop-video dataset: objects × attribute samples, 30 frames, 4 views.

    Writes OUT/objects/ (canonical Gaussians + anchors, once per object), OUT/samples/ (frames,
    trajectory, cameras, attributes, mp4 per view) and OUT/manifest.json. Rerunning the same
    command resumes a killed run; a run with other settings into the same OUT is refused."""
    from ..data.make import make_dataset
    from ..data.plan import parse_shard
    from ..data.settings import make_settings

    given = given_options(ctx)
    values = {
        field: ctx.params[option]
        for option, field in SETTINGS_OPTIONS.items()
        if config is None or option in given
    }
    if values.get("stretch_range") is not None:
        values["stretch_range"] = (1.0, float(values["stretch_range"]))
    for name in ("exposure_range_s", "readout_range_s"):
        if values.get(name) is not None:
            values[name] = (0.0, float(values[name]))
    if values.get("objaverse_uids"):
        values["objaverse_uids"] = str(values["objaverse_uids"])
    settings = make_settings(preset, config, **values)
    # paths are stored absolute (the manifest, the fingerprint): resolved against the cwd
    if settings.source not in NAMED_SOURCES:
        settings = replace(settings, source=str(Path(settings.source).resolve()))
    if settings.objaverse_uids:
        settings = replace(settings, objaverse_uids=str(Path(settings.objaverse_uids).resolve()))
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

    from ..data.show import contact_sheet, summary

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
    from ..data.make import merge_shards

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
    from ..assets.asset import write_asset
    from ..data.dataset import DropDataset

    dataset = DropDataset(root, allow_incomplete=True, verify=False)
    write_asset(dataset.asset(dataset.index_of(sample)), out, overwrite=overwrite)
    typer.echo(f"wrote {out}")


@data_app.command("video")
@user_errors
def data_video(
    root: Path = typer.Argument(..., help="Dataset folder."),
    sample: str = typer.Argument(..., help="Sample id (see manifest.json)."),
    out: Path = typer.Argument(..., help="Folder to write video.mp4, camera.json, gaussians.ply."),
    view: int = typer.Option(0, help="View 0–3."),
    lens: bool = typer.Option(
        False,
        help="Write the camera's 35 mm-equivalent focal length into video.mp4's metadata, as a "
        "phone does (predict then reads the field of view from it).",
    ),
    overwrite: bool = typer.Option(False, help="Replace an existing folder."),
):
    """Write one sample as a user would bring it to `reconphys predict`: its encoded video
    (view_V.mp4), the camera file and the object's Gaussians placed as in frame 0."""
    from ..assets.ply import write_ply
    from ..capture import CameraSpec, write_camera
    from ..capture.lens import focal_35mm_from_pixels
    from ..data.dataset import DropDataset
    from ..data.storage import video_name
    from ..render.video import FOCAL_35MM_KEY, copy_with_metadata

    if not 0 <= view < 4:
        raise InputError(f"expected 0–3, got {view}", field="--view")
    check_new_output(out, overwrite)
    dataset = DropDataset(root, views=[view], allow_incomplete=True, verify=False)
    index = dataset.index_of(sample)
    meta = dataset.samples[index]
    video = root / meta["dir"] / video_name(view)
    if not video.is_file():
        raise InputError("the sample's video is missing", source=str(video))
    item = dataset[index]
    height, width = item["frames"].shape[2:4]
    camera = CameraSpec(item["K"][0].double(), item["world_to_cam"][0].double(), width, height)
    with atomic_folder(out, overwrite=overwrite) as staging:
        if lens:  # an iPhone writes a whole number of millimetres
            focal = focal_35mm_from_pixels(float(camera.K[1, 1]), width, height)
            copy_with_metadata(video, staging / "video.mp4", {FOCAL_35MM_KEY: f"{focal:.0f}"})
        else:
            shutil.copyfile(video, staging / "video.mp4")
        write_camera(staging / "camera.json", camera)
        write_ply(staging / "gaussians.ply", dataset.asset(index).gaussians)
        # frame 0's lowest anchor above the ground, as stored: what `predict --drop-height` takes
        drop_height = round(dataset.meta(index)["initial_state"]["drop_height"], 4)
        truth = {"sample": sample, "view": view, **meta["attributes"], "drop_height_m": drop_height}
        (staging / "truth.json").write_text(json.dumps(truth, indent=1) + "\n")
    typer.echo(f"wrote {out}: video.mp4, camera.json, gaussians.ply, truth.json")
