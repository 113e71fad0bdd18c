"""Mean mask IoU of the segmenter against its logit threshold, per dataset
(docs/usage.md#masks-without-a-clean-plate).

For view 0 of each sample of the given realistic-look datasets' splits, the mean IoU of the
segmenter's masks (logits above the threshold, main blob kept) with the stored true masks, for
each threshold. Run it on clips of meshes held out of the segmenter's training and of the test
sets (validation), at the resolutions a choice must hold at.

    python benchmarks/mask_threshold.py VAL64:test VAL96:test VAL128:test
"""

from __future__ import annotations

import argparse
import platform

import numpy as np
import torch
from common import mean_mask_iou

from reconphys.data import DropDataset
from reconphys.models.mask_segmenter import clip_logits, keep_main_blob, load_mask_segmenter


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("data", nargs="+", help="FOLDER:SPLIT")
    parser.add_argument(
        "--thresholds", default="-3,-2,-1,-0.5,0,0.5,1", help="logits, comma-separated"
    )
    parser.add_argument("--segmenter", default=None, help="weights (default: the shipped ones)")
    args = parser.parse_args()
    torch.set_num_threads(2)
    thresholds = [float(t) for t in args.thresholds.split(",")]
    model = load_mask_segmenter(args.segmenter)
    print(f"the segmenter's masks: logits > 0; {platform.machine()}, torch {torch.__version__}")
    pooled = {}
    for spec in args.data:
        folder, _, split = spec.partition(":")
        dataset = DropDataset(folder, split=split or "test", views=[0])
        scores = {}
        for index in range(len(dataset)):
            frames, truth = dataset[index]["frames"][0], dataset.masks(index)[0].float()
            logits = clip_logits(model, frames)
            for threshold in thresholds:
                masks = keep_main_blob(logits > threshold).float()
                scores.setdefault(threshold, []).append(mean_mask_iou(masks, truth))
        for key, values in scores.items():
            pooled.setdefault(key, []).extend(values)
        print(f"{spec} ({len(dataset)} clips):")
        for threshold, values in sorted(scores.items()):
            print(f"  threshold {threshold:+.1f}: IoU {np.mean(values):.4f}")
    if len(args.data) > 1:
        print("pooled:")
        for threshold, values in sorted(pooled.items()):
            print(f"  threshold {threshold:+.1f}: IoU {np.mean(values):.4f}")


if __name__ == "__main__":
    main()
