"""A mesh folder for training that holds out a dataset's test objects.

Copies the folder of every usable pybullet mesh (``reconphys.data.sources.PybulletSource``: the
wheel's ``random_urdfs`` and a few named meshes, broken files left out) into OUT, except the
objects of DATASET's test split, so that ``make-data --source OUT`` makes training videos of
objects DATASET never tests on. Meshes at the top of pybullet_data (bunny, duck, …) are skipped:
their folder is the whole package. `make model` runs it (Makefile; docs/training.md "Track
network").

    python benchmarks/held_out_meshes.py data/pyb data/pybullet_meshes
"""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

from reconphys.data.sources import PybulletSource
from reconphys.data.storage import read_manifest


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "dataset", type=Path, help="a make-data folder: its test objects are left out"
    )
    parser.add_argument("out", type=Path, help="the mesh folder to write")
    args = parser.parse_args()
    manifest = read_manifest(args.dataset)
    held_out = {o["id"] for o in manifest["objects"] if o["split"] == "test"}
    source = PybulletSource()
    copied = skipped = 0
    for path in source.paths:
        relative = path.relative_to(source.root)
        if relative.as_posix() in held_out or relative.parent == Path("."):
            skipped += 1
            continue
        target = args.out / relative.parent
        if not target.exists():
            shutil.copytree(path.parent, target)
        copied += 1
    held = f"{len(held_out)} test objects of {args.dataset}"
    print(f"{copied} meshes in {args.out}; left out {skipped} ({held} and top-level meshes)")


if __name__ == "__main__":
    main()
