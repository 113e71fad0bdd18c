"""Is ``reconphys predict VIDEO`` as good as the model on its test split?

For every sample of a split, the sample is exported as a user would bring it (``data video``: the
H.264 mp4 of the model's view, camera.json, the frame-0 Gaussians) and predicted through the
video path (decode → background subtraction → placement check → velocity estimate → physics
network → asset). The attribute errors are compared with the same model on the stored frames
(what ``evaluate --methods reconphys`` scores) and with the trivial predictor (the training
medians stored in the model), as MAE of log k/m, log d/m and f. Also: the estimated initial
linear velocity against the truth (m/s), and whether the given Gaussians were kept in place.

    python benchmarks/check_video_path.py data/cpu_small --split test
"""

from __future__ import annotations

import argparse
import json
import math
import statistics
import sys
import tempfile
from pathlib import Path

from common import machine_description
from typer.testing import CliRunner

from reconphys.cli import app
from reconphys.pipeline.predict import predict
from reconphys.threads import set_cpu_threads

OBSERVABLES = ("log k/m", "log d/m", "f")


def observables(a: dict) -> tuple[float, float, float]:
    return (math.log(a["stiffness"] / a["mass"]), math.log(a["damping"] / a["mass"]), a["friction"])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("data")
    parser.add_argument("--split", default="test")
    parser.add_argument("--model", default=None)
    parser.add_argument("--threads", type=int, default=2)
    args = parser.parse_args()
    set_cpu_threads(args.threads)
    manifest = json.loads((Path(args.data) / "manifest.json").read_text())
    samples = [s for s in manifest["samples"] if s["split"] == args.split]
    print(f"# {' '.join(sys.argv)}")
    print(f"# {machine_description('cpu')}")
    errors = {path: {o: [] for o in OBSERVABLES} for path in ("video", "stored", "trivial")}
    velocity_errors, placements = [], []
    runner = CliRunner()
    with tempfile.TemporaryDirectory() as tmp:
        for entry in samples:
            bundle = Path(tmp) / entry["id"]
            result = runner.invoke(app, ["data", "video", args.data, entry["id"], str(bundle)])
            if result.exit_code != 0:
                raise SystemExit(result.output)
            video = predict(
                bundle / "video.mp4",
                camera=bundle / "camera.json",
                gaussians=bundle / "gaussians.ply",
                model=args.model,
                refine=False,
            )
            stored = predict(args.data, sample=entry["id"], model=args.model, refine=False)
            medians = video.details.get("trivial") or _medians(stored)
            truth = observables(entry["attributes"])
            for path, attributes in (
                ("video", video.attributes),
                ("stored", stored.attributes),
                ("trivial", medians),
            ):
                for name, p, t in zip(OBSERVABLES, observables(attributes), truth, strict=True):
                    errors[path][name].append(abs(p - t))
            meta = json.loads((Path(args.data) / entry["dir"] / "sample.json").read_text())
            true_v = meta["initial_state"]["linear_velocity"]
            estimated = video.details["initial_velocity"]["linear_m_s"]
            velocity_errors.append(math.dist(true_v, estimated))
            placements.append(video.details["placement"])
            row = " ".join(
                f"{p:6.3f}/{s:6.3f}/{t:6.3f}"
                for p, s, t in zip(
                    observables(video.attributes),
                    observables(stored.attributes),
                    truth,
                    strict=True,
                )
            )
            print(
                f"{entry['id']:18s} video/stored/truth {row}  |Δv| {velocity_errors[-1]:.2f} "
                f"m/s  {video.details['placement']}",
                flush=True,
            )
    print(
        f"\nMAE over {len(samples)} {args.split} samples   "
        + "  ".join(f"{o:>8s}" for o in OBSERVABLES)
    )
    for path in ("video", "stored", "trivial"):
        print(
            f"{path:32s} "
            + "  ".join(f"{statistics.fmean(errors[path][o]):8.3f}" for o in OBSERVABLES)
        )
    print(
        f"initial linear velocity error: median {statistics.median(velocity_errors):.2f} m/s; "
        f"given Gaussians kept in place on {placements.count('as-is')}/{len(placements)}"
    )


def _medians(result) -> dict:
    from reconphys.models.shipped import load_predictor

    metadata = load_predictor(result.details["model"]).metadata
    return metadata["training"]["attribute_medians"]


if __name__ == "__main__":
    main()
