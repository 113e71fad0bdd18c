"""``reconphys demo``: the shipped example recordings and the demo's report (docs/usage.md).

An example is a folder of ``src/reconphys/examples/``: what a user brings to ``predict``
(``video.mp4``, ``camera.json``) and ``truth.json``, the attributes the clip was simulated with,
which ``predict`` never reads. The demo runs ``predict``'s default path on it (no PLY, no ground
truth) and writes ``summary.md``: the answer beside the truth and beside the guess a user makes
without the video, where each number came from, and what to try next.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

from ..errors import InputError
from ..io import read_json
from ..physics import ATTRIBUTES
from ..physics.model import ATTRIBUTE_RANGES
from .search import OBSERVABLES, observables

EXAMPLES_DIR = Path(__file__).resolve().parent.parent / "examples"
EXAMPLE_FORMAT, EXAMPLE_VERSION = "reconphys.example", 1
# The realistic look (a floor, a backdrop, a shadow, another camera, H.264): what a user films.
# ``duck_toss`` is the same toss in the plain look (the object on black, the dataset's camera).
DEFAULT_EXAMPLE = "duck_toss_scene"
FUTURE_FRAMES = 60  # frames the preview simulates past the end of the recording
OBSERVABLE_LABELS = {
    "log_k_over_m": "log k/m (stiffness / mass, ln 1/s²)",
    "log_d_over_m": "log d/m (damping / mass, ln 1/s)",
    "friction": "friction coefficient",
}


@dataclass(frozen=True)
class Example:
    name: str
    folder: Path
    truth: dict  # truth.json: description, source, launch, attributes (SI), initial velocity

    @property
    def video(self) -> Path:
        return self.folder / "video.mp4"

    @property
    def camera(self) -> Path:
        return self.folder / "camera.json"


def example_names(root: Path = EXAMPLES_DIR) -> list[str]:
    """The examples shipped in ``root`` (folders holding a ``truth.json``), sorted."""
    if not root.is_dir():
        return []
    return sorted(p.name for p in root.iterdir() if (p / "truth.json").is_file())


def load_example(name: str, root: Path = EXAMPLES_DIR) -> Example:
    """The example ``name``; InputError naming it (and the known ones) when it is missing or
    incomplete."""
    folder = root / name
    if not (folder / "truth.json").is_file():
        raise InputError(f"no such example; known: {example_names(root)}", field="--example")
    truth = read_json(folder / "truth.json", EXAMPLE_FORMAT, EXAMPLE_VERSION)
    attributes = truth.get("attributes")
    if not isinstance(attributes, dict) or set(attributes) < set(ATTRIBUTE_RANGES):
        raise InputError("needs the four true attributes", source=str(folder / "truth.json"),
                         field="attributes")  # fmt: skip
    example = Example(name, folder, truth)
    for path in (example.video, example.camera):
        if not path.is_file():
            raise InputError("file not found (the example is incomplete)", source=str(path))
    return example


def true_observables(attributes: dict) -> dict[str, float]:
    """What a video determines (docs/design.md#physical-model), from the four attributes:
    :func:`.search.observables` by name (natural logs of the SI ratios; friction)."""
    physics = SimpleNamespace(**{name: float(attributes[name]) for name in ATTRIBUTES})
    return dict(zip(OBSERVABLES, observables(physics).tolist(), strict=True))


def prior_centre() -> dict[str, float]:
    """The guess without the video: the middle of each observable's prior (mass, stiffness and
    damping log-uniform over the docs/design.md#attribute-ranges ranges, friction uniform), i.e.
    the median of the training data's log k/m, log d/m and f."""

    def log_mid(name: str) -> float:
        low, high = ATTRIBUTE_RANGES[name]
        return 0.5 * (math.log(low) + math.log(high))

    low, high = ATTRIBUTE_RANGES["friction"]
    return {
        "log_k_over_m": log_mid("stiffness") - log_mid("mass"),
        "log_d_over_m": log_mid("damping") - log_mid("mass"),
        "friction": 0.5 * (low + high),
    }


def summary_markdown(example: Example, prediction: dict, wall_seconds: float, out: Path) -> str:
    """The demo's ``summary.md``: ``prediction`` is what ``predict`` wrote (prediction.json), so
    every number here is one ``predict`` computed."""
    truth = true_observables(example.truth["attributes"])
    found = prediction["observables"]
    network = true_observables(prediction["feed_forward"])
    intervals = prediction.get("intervals") or {}
    search = prediction.get("search")
    undetermined = set((search or {}).get("undetermined", []))
    with_belief = search is not None and search.get("network_sigma") is not None
    not_shown = (
        "no: the network's belief decides"
        if with_belief
        else ("no: too wide, the network's value kept")
    )
    guess = prior_centre()
    rows = []
    for name, label in OBSERVABLE_LABELS.items():
        if name in intervals:
            lo, hi = intervals[name]
            inside = "yes" if lo <= truth[name] <= hi else "no"
            interval = f"[{lo:.2f}, {hi:.2f}] (truth inside: {inside})"
            shown = not_shown if name in undetermined else "yes"
            shown = "– (--no-refine: the network's belief)" if search is None else shown
        else:
            interval, shown = "– (--no-refine)", "–"
        rows.append(
            f"| {label} | {truth[name]:.2f} | **{found[name]:.2f}** | {network[name]:.2f} | "
            f"{interval} | {shown} | {guess[name]:.2f} |"
        )
    timings = prediction["timings_s"]
    steps = ", ".join(f"{step} {seconds:.2f}" for step, seconds in timings.items())
    recording = prediction["input"]
    velocity = prediction.get("initial_velocity", {}).get("linear_m_s")
    true_velocity = example.truth.get("initial_velocity_m_s")
    lines = [
        f"# reconphys demo: {example.name}",
        "",
        f"**In**: `{example.video.name}` + `{example.camera.name}` — "
        f"{example.truth['description']}."
        f" {recording['frames']} frames at {recording['size'][1]}×{recording['size'][0]}. "
        "No PLY and no ground truth were given: the Gaussians come from the 3DGS predictor "
        "(frame 0), the physics from the track network, then the batched search.",
        "",
        f"**Out**: a simulation-ready asset in `{out / 'asset'}` "
        f"({prediction['gaussians']} Gaussians, {prediction['anchors']} anchors, "
        f"{prediction['springs']} springs), `preview.mp4` (recording | re-simulation, then "
        f"{FUTURE_FRAMES} frames of future), `contact_sheet.png`, `prediction.json`.",
        "",
        f"**Time**: {wall_seconds:.1f} s in all on this machine; steps (s): {steps}.",
        "",
        "| observable | true | predicted | network alone | 10–90 % interval | shown by the "
        "video? | guess without the video |",
        "|---|---|---|---|---|---|---|",
        *rows,
        "",
        "*predicted*: what the asset holds — "
        + (
            "the median of the search's fit to the video times the network's own belief (a "
            "normal at its answer, σ from its members' spread), so the network's answer where "
            "the video shows little and the fit's where it shows much"
            if with_belief
            else "the search's best fit where the video shows the observable; where its interval "
            "is too wide, the network's value"
        )
        + ". *guess without the video*: the middle of the training prior. True values: "
        "`truth.json` (the simulation that made the clip); predict never read them.",
    ]
    if velocity is not None and true_velocity is not None:
        lines += [
            "",
            f"Initial velocity (m/s): estimated {_vector(velocity)}, true "
            f"{_vector(true_velocity)} (from the masks' free fall and growth: frames 0–3 "
            "decide a release from rest, the whole fall reads a motion).",
        ]
    spin = prediction.get("initial_velocity", {}).get("angular")
    true_spin = example.truth.get("initial_angular_velocity_rad_s")
    if spin is not None and true_spin is not None:
        view_axis = read_json(example.camera)["world_to_cam"][2][:3]  # camera z in the world
        true_roll = sum(a * w for a, w in zip(view_axis, true_spin, strict=True))
        lines += [
            "",
            f"Spin about the viewing axis (rad/s): estimated {spin['about_view_rad_s']:+.2f} "
            + (f"(± {sd:.2f}; " if (sd := spin.get("about_view_sd_rad_s")) is not None else "(")
            + ("kept" if spin["shown"] else "not shown by the free fall: 0 kept")
            + f"), true {true_roll:+.2f}, from the free-fall frames rendered and compared; the "
            f"turns about the image's axes are not read (true spin {_vector(true_spin)}).",
        ]
    rating = prediction.get("input", {}).get("masks_rating")
    if rating is not None:
        low, high = rating["expected_iou_10_90"]
        lines += [
            "",
            f"Masks: the mask segmenter's, their IoU with the object expected near "
            f"{rating['expected_iou']:.2f} ({low:.2f}–{high:.2f}, 10–90 %; from the share of "
            'unsure pixels at their outline, docs/usage.md "How sure the masks are")'
            + (": check their outline in the preview" if "warning" in rating else "")
            + ".",
        ]
    lines += [
        "",
        f"Geometry: {prediction['geometry']}"
        + (f" ({prediction['gs_model_choice']})" if "gs_model_choice" in prediction else "")
        + ". One view shows one side: the hidden sides are the predictor's guess (docs/usage.md "
        '"The 3DGS predictor"); give the object\'s PLY or mesh (`--gaussians`, `--mesh`) when '
        "you have one.",
        "",
        "## Next",
        "",
        "```bash",
        f"reconphys view {out / 'asset'}                                  # drop, grab and "
        "stretch it in the browser",
        f"reconphys simulate {out / 'asset'} --push 0.1,0,0 --out {out / 'push'}   # grab, "
        "push 10 cm, release",
        f"reconphys export {out / 'asset'} --format mjcf --out {out / example.name}.xml"
        "   # MuJoCo (or --format newton)",
        "```",
        "",
    ]
    return "\n".join(lines)


def _vector(values) -> str:
    return "(" + ", ".join(f"{float(v):+.2f}" for v in values) + ")"
