"""How well predict's check of a given shape tells the object's own Gaussians from the same turned
(docs/usage.md#the-colours-of-a-given-shape).

For view 0 of every test sample of a realistic-look dataset (``make-data --scene realistic``),
frame 0 and its mask from the mask segmenter, as ``predict`` reads a recording: the sample's
true Gaussians, and the same turned about their centre by 90° about x, 90° about y, 180° about x
and 90° about z. For each, as given and moved onto the mask by ``fit_to_mask`` (what
``--placement auto`` does with a shape that does not match as given): the silhouette IoU
(``capture.placement.silhouette_iou``) and the colours' chromaticity correlation
(``colour_agreement``; None where it cannot tell). A shape is kept as ``predict --placement
auto`` keeps it: as given when it matches, else moved onto the mask when that matches — its IoU
reaching ``MIN_PLACED_IOU`` (``MIN_COLOURED_IOU`` where its colours agree) and its colours,
where judged, ``MIN_COLOUR_AGREEMENT``; the silhouette alone: its IoU reaching
``MIN_PLACED_IOU`` either way.

Prints the true shapes kept and the turned ones let by, with the silhouette alone and with both
checks, and the range of each score.

    python benchmarks/placement_check.py data/mval128 [--limit 40] [--out rows.json]
"""

from __future__ import annotations

import argparse
import json
import math
import platform
import time
from dataclasses import replace

import numpy as np
import torch

from reconphys.capture.camera import CameraSpec
from reconphys.capture.placement import fit_to_mask, placement_scores
from reconphys.data import DropDataset
from reconphys.geometry import axis_angle_to_matrix, matrix_to_quaternion, quaternion_multiply
from reconphys.models.mask_segmenter import MAX_SIDE, load_mask_segmenter, segment_clip
from reconphys.pipeline.predict import (
    MIN_COLOUR_AGREEMENT,
    MIN_COLOURED_IOU,
    MIN_PLACED_IOU,
    placement_matches,
)

TURNS = {  # name → (axis, angle in radians), about the Gaussians' centre
    "x90": ((1.0, 0.0, 0.0), math.pi / 2),
    "y90": ((0.0, 1.0, 0.0), math.pi / 2),
    "x180": ((1.0, 0.0, 0.0), math.pi),
    "z90": ((0.0, 0.0, 1.0), math.pi / 2),
}


def turned(gaussians, axis, angle):
    rotation = axis_angle_to_matrix(torch.tensor(axis, dtype=torch.float64) * angle)
    centre = gaussians.means.double().mean(0)
    means = (gaussians.means.double() - centre) @ rotation.T + centre
    spin = matrix_to_quaternion(rotation).to(gaussians.quats).expand_as(gaussians.quats)
    return replace(
        gaussians, means=means.to(gaussians.means), quats=quaternion_multiply(spin, gaussians.quats)
    )


def scores(gaussians, frame, mask, camera) -> dict:
    iou, colour = placement_scores(gaussians, mask, camera, frame)
    return {"iou": iou, "colour": colour}


def matches(score: dict, colours: bool) -> bool:
    """predict's rule (placement_matches, and the colours where judged); without ``colours``,
    the silhouette's alone."""
    if not colours:
        return score["iou"] >= MIN_PLACED_IOU
    agree = score["colour"] is None or score["colour"] >= MIN_COLOUR_AGREEMENT
    return placement_matches(score["iou"], score["colour"]) and agree


def kept(row: dict, colours: bool = True) -> bool:
    """--placement auto: kept as given when it matches, else moved onto the mask and kept when
    that matches."""
    return matches(row["given"], colours) or matches(row["fitted"], colours)


def placed(gaussians, frame, mask, camera) -> dict:
    fitted = fit_to_mask(gaussians, mask, camera)
    return {
        "given": scores(gaussians, frame, mask, camera),
        "fitted": scores(fitted, frame, mask, camera),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("data", help="a realistic-look dataset (its test split)")
    parser.add_argument("--limit", type=int, default=None, help="the first N test samples")
    parser.add_argument("--out", default=None, help="JSON file of the per-sample rows")
    args = parser.parse_args()
    torch.set_num_threads(1)
    dataset = DropDataset(args.data, split="test", views=[0])
    segmenter = load_mask_segmenter(None)
    count = len(dataset) if args.limit is None else min(args.limit, len(dataset))
    rows, start = [], time.perf_counter()
    for index in range(count):
        item = dataset[index]
        clip = item["frames"][0]  # [T, H, W, 3]
        camera = CameraSpec(
            item["K"][0].double(), item["world_to_cam"][0].double(), clip.shape[2], clip.shape[1]
        )
        mask = segment_clip(segmenter, clip, MAX_SIDE)[0].float()
        frame = clip[0].float() * mask[..., None]  # as predict's observation holds it
        truth = dataset.asset(index).gaussians
        row = {"id": item["id"], "true": placed(truth, frame, mask, camera)}
        for name, (axis, angle) in TURNS.items():
            row[name] = placed(turned(truth, axis, angle), frame, mask, camera)
        rows.append(row)
        print(f"{index + 1}/{count} {item['id']}", flush=True)
    true = [row["true"] for row in rows]
    wrong = [row[name] for row in rows for name in TURNS]
    print(
        f"\n{args.data}: {count} clips, {platform.processor() or platform.machine()}, "
        f"torch {torch.__version__}, {time.perf_counter() - start:.0f} s; "
        f"bars IoU ≥ {MIN_PLACED_IOU} (≥ {MIN_COLOURED_IOU} where the colours agree), colours ≥ "
        f"{MIN_COLOUR_AGREEMENT}"
    )
    for label, colours in (("silhouette alone", False), ("silhouette and colours", True)):
        kept_true = sum(kept(s, colours) for s in true)
        let_by = sum(kept(s, colours) for s in wrong)
        print(
            f"{label}: true kept {kept_true}/{len(true)}, turned let by {let_by}/{len(wrong)} "
            f"({100 * let_by / max(len(wrong), 1):.1f} %)"
        )
    groups = {
        "true, as given": [row["given"] for row in true],
        "turned, moved onto the mask": [row["fitted"] for row in wrong],
    }
    for label, group in groups.items():
        iou = np.array([s["iou"] for s in group])
        judged = np.array([s["colour"] for s in group if s["colour"] is not None])
        colour = (
            f"colours judged {len(judged)}/{len(group)}, {judged.min():.3f}–{judged.max():.3f} "
            f"(median {np.median(judged):.3f})"
            if len(judged)
            else "colours never judged"
        )
        print(f"{label}: IoU {iou.min():.3f}–{iou.max():.3f} (mean {iou.mean():.3f}); {colour}")
    if args.out:
        with open(args.out, "w") as f:
            json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()
