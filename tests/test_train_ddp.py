"""DDP: ``torchrun --nproc_per_node 2`` on CPU (gloo) runs the tiny config in step with one process.

Two ranks with batch 1 each must end with identical weights, read disjoint halves of every global
batch, leave the writing to rank 0, and follow the single-process run with batch 2 (same global
batch, gradients averaged) up to float round-off.
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
from pathlib import Path

import torch

from reconphys.train.config import load_config
from reconphys.train.data import TrainingSamples, step_indices
from reconphys.train.trainer import train

TINY = Path(__file__).resolve().parent.parent / "configs" / "tiny.toml"
STEPS = 2

DRIVER = textwrap.dedent(
    """
    import json, os, sys
    import torch
    from reconphys.train import trainer
    from reconphys.train.config import load_config

    out, config_path, *overrides = sys.argv[1:]
    seen = []
    collate = trainer.collate

    def recording_collate(items):
        batch = collate(items)
        seen.append(batch.ids)
        return batch

    trainer.collate = recording_collate  # what this rank read, step by step
    result = trainer.train(load_config(config_path, overrides), progress=False)
    rank = int(os.environ["RANK"])
    weights = {k: v.detach().clone() for k, v in result.model.state_dict().items()}
    torch.save(weights, os.path.join(out, f"rank{rank}.pt"))
    with open(os.path.join(out, f"rank{rank}.json"), "w") as f:
        json.dump({"ids": seen, "world_size": int(os.environ["WORLD_SIZE"])}, f)
    """
)


def test_two_process_cpu_ddp_matches_one_process(tmp_path):
    driver = tmp_path / "driver.py"
    driver.write_text(DRIVER)
    out = tmp_path / "ddp"
    overrides = [f"train.out={out}", f"train.steps={STEPS}", "train.checkpoint_every=1"]
    command = [
        sys.executable, "-m", "torch.distributed.run", "--standalone", "--nnodes", "1",
        "--nproc_per_node", "2", str(driver), str(tmp_path), str(TINY), *overrides,
    ]  # fmt: skip
    done = subprocess.run(command, capture_output=True, text=True, timeout=180)
    assert done.returncode == 0, done.stdout[-3000:] + done.stderr[-3000:]

    ranks = [torch.load(tmp_path / f"rank{r}.pt") for r in range(2)]
    assert all(torch.equal(ranks[0][k], ranks[1][k]) for k in ranks[0])
    # only rank 0 writes: one log line per step, one checkpoint, one model
    log = [json.loads(line) for line in (out / "log.jsonl").read_text().splitlines()]
    assert [r["step"] for r in log] == list(range(1, STEPS + 1))
    assert (out / "checkpoint.pt").is_file() and (out / "model.safetensors").is_file()
    assert json.loads((out / "model.json").read_text())["training"]["world_size"] == 2

    # each rank read its half of every global batch
    seen = [json.loads((tmp_path / f"rank{r}.json").read_text())["ids"] for r in range(2)]
    config = load_config(TINY, overrides)
    data = TrainingSamples(config.data)
    for step in range(1, STEPS + 1):
        batch = step_indices(step, len(data), config.train.batch_size, config.train.seed)
        expected = sorted(data.sample_id(i) for i in batch)
        halves = seen[0][step - 1], seen[1][step - 1]
        assert len(halves[0]) == len(halves[1]) == 1
        assert sorted(halves[0] + halves[1]) == expected

    # the same optimisation as one process with the whole batch
    single = train(
        load_config(TINY, [f"train.out={tmp_path / 'single'}", f"train.steps={STEPS}"]),
        progress=False,
        log=lambda line: None,
    )
    for record, reference in zip(log, single.records, strict=True):
        assert abs(record["loss"] - reference["loss"]) <= 1e-5 * abs(reference["loss"])
    reference_weights = single.model.state_dict()
    for key, value in ranks[0].items():
        torch.testing.assert_close(value, reference_weights[key], rtol=1e-4, atol=1e-6)
