"""Does a physics model fit the observables on its training videos, and on held-out ones?

Runs the network alone (no simulation) on every sample of the train and test splits of a
dataset, and prints the MAE of log k/m, log d/m and f beside the trivial predictor (the training
split's medians) and their ratio. A model that is no better than trivial on its *training*
videos underfits (the network does not extract the signal); one far better on training than on
test videos overfits.

    python benchmarks/observable_fit.py data/cpu_small [--model runs/X] [--threads 1]
"""

from __future__ import annotations

import argparse
import statistics

import torch

from reconphys.data.dataset import DropDataset
from reconphys.eval.metrics import observable_attributes
from reconphys.models.model_input import predictor_frames
from reconphys.models.shipped import load_predictor
from reconphys.physics import ATTRIBUTES
from reconphys.threads import set_cpu_threads

OBSERVABLES = ("log k/m", "log d/m", "f")


def observables(attributes: dict[str, torch.Tensor]) -> torch.Tensor:  # [N, 3]
    obs = observable_attributes(attributes)
    return torch.stack([obs["log_k_over_m"], obs["log_d_over_m"], obs["friction"]], -1)


def predict_split(model, root: str, split: str) -> tuple[torch.Tensor, torch.Tensor]:
    """(predicted, true) observables [N, 3] of a split's input views."""
    dataset = DropDataset(root, split, views=[model.view], frames=range(model.num_frames))
    predicted, true = [], []
    for i in range(len(dataset)):
        item = dataset[i]
        frames = predictor_frames(item["frames"][0], item["K"][0], model.model.config.resolution)
        with torch.no_grad():
            out = model.model(frames)
        predicted.append({n: out[n][0] for n in ATTRIBUTES})
        true.append(dict(zip(ATTRIBUTES, item["attributes"], strict=True)))
    return observables(_stack(predicted)), observables(_stack(true))


def _stack(rows: list[dict[str, torch.Tensor]]) -> dict[str, torch.Tensor]:
    return {n: torch.stack([r[n] for r in rows]).double() for n in ATTRIBUTES}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("data", help="dataset folder (make-data)")
    parser.add_argument("--model", default=None, help="model path (default: the shipped one)")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args()
    set_cpu_threads(args.threads)
    model = load_predictor(args.model)
    splits = {split: predict_split(model, args.data, split) for split in ("train", "test")}
    medians = torch.tensor(
        [statistics.median(splits["train"][1][:, j].tolist()) for j in range(len(OBSERVABLES))]
    )
    print(f"model: {model.path}")
    print(f"{'split':6} {'observable':10} {'model MAE':>9} {'trivial MAE':>11} {'ratio':>6}")
    for split, (predicted, true) in splits.items():
        model_mae = (predicted - true).abs().mean(0)
        trivial_mae = (medians - true).abs().mean(0)
        for j, name in enumerate(OBSERVABLES):
            ratio = trivial_mae[j] / model_mae[j]
            print(f"{split:6} {name:10} {model_mae[j]:9.3f} {trivial_mae[j]:11.3f} {ratio:5.2f}×")


if __name__ == "__main__":
    main()
