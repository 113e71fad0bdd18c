"""Mesh folders for held-out evaluation and training, from the pybullet wheel.

``DATASET OUT``: copies the folder of every usable pybullet mesh (``PybulletSource``: the wheel's
``random_urdfs`` and a few named meshes, broken files left out) into OUT, except the objects of
DATASET's test split, so that ``make-data --source OUT`` makes training videos of objects
DATASET never tests on. Meshes at the top of pybullet_data (bunny, duck, …) are skipped: their
folder is the whole package. `make model` runs it (docs/training.md "Track network and a data
curve").

``--test DATASET OUT``: only DATASET's test objects (their realistic-look drops: a test set held
out by object for a model trained on the folder above; docs/training.md "Object-centric input").

``--validation FOLDER OUT``: the validation meshes of the shipped physics ensemble — the objects
of FOLDER (the folder above) that ``configs/data_pybullet.toml``'s plan puts after the first
``data.objects`` of ``configs/track_pybullet.toml`` (849): meshes neither the network nor any test
set has seen, for calibrations at other sizes (docs/training.md "Intervals").

``--others OUT``: the wheel's other meshes — robot links, toys, props (laikago, kuka, xarm,
racecar, …; ``.obj``/``.stl`` outside ``random_urdfs``, collision hulls and the named meshes of
the pybullet source left out) — flattened into OUT: a mesh folder none of the pybullet source's
objects is in (docs/evaluation.md "another mesh folder").

    python benchmarks/held_out_meshes.py data/pyb data/pybullet_meshes
    python benchmarks/held_out_meshes.py --others data/other_meshes
    python benchmarks/held_out_meshes.py --validation data/pybullet_meshes data/val_meshes
"""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path

from reconphys.assets.mesh import PYBULLET_NAMED_MESHES
from reconphys.config_loader import read_table
from reconphys.data.plan import plan_objects
from reconphys.data.settings import make_settings
from reconphys.data.sources import FolderSource, PybulletSource
from reconphys.data.storage import read_manifest


def training_meshes(dataset: Path, out: Path, test: bool = False) -> None:
    """Every pybullet mesh except DATASET's test objects into OUT (``test``: only those)."""
    manifest = read_manifest(dataset)
    held_out = {o["id"] for o in manifest["objects"] if o["split"] == "test"}
    source = PybulletSource()
    copied = skipped = 0
    for path in source.paths:
        relative = path.relative_to(source.root)
        if (relative.as_posix() in held_out) != test or relative.parent == Path("."):
            skipped += 1
            continue
        target = out / relative.parent
        if not target.exists():
            shutil.copytree(path.parent, target)
        copied += 1
    held = f"{len(held_out)} test objects of {dataset}"
    if test:
        print(f"{copied} meshes in {out}: the {held}")
    else:
        print(f"{copied} meshes in {out}; left out {skipped} ({held} and top-level meshes)")


def validation_meshes(folder: Path, out: Path) -> None:
    """The objects of FOLDER that the shipped ensemble's recipe never trained on → OUT."""
    configs = Path(__file__).resolve().parent.parent / "configs"
    settings = make_settings(config=configs / "data_pybullet.toml", source=str(folder))
    trained = int(read_table(configs / "track_pybullet.toml")["data"]["objects"])
    planned = [p for p in plan_objects(settings, FolderSource(folder)) if p.split == "train"]
    for p in planned[trained:]:
        target = out / Path(p.ref.id).parent
        if not target.exists():
            shutil.copytree(folder / Path(p.ref.id).parent, target)
    print(f"{len(planned) - trained} meshes in {out}: {folder}'s objects after the first {trained}")


def other_meshes(out: Path) -> None:
    root = PybulletSource().root
    out.mkdir(parents=True, exist_ok=True)
    copied = 0
    for path in sorted(root.rglob("*")):
        relative = path.relative_to(root).as_posix()
        if (
            path.suffix.lower() not in (".obj", ".stl")
            or relative.startswith("random_urdfs/")
            or relative in PYBULLET_NAMED_MESHES
            or "_coll" in path.stem
            or "vhacd" in path.stem.lower()
        ):
            continue
        shutil.copyfile(path, out / relative.replace("/", "__"))
        copied += 1
    print(f"{copied} meshes in {out} (pybullet_data outside random_urdfs)")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--others", action="store_true", help="the wheel's other meshes → OUT")
    parser.add_argument("--test", action="store_true", help="DATASET's test objects only → OUT")
    parser.add_argument(
        "--validation", action="store_true", help="FOLDER's meshes the model never saw → OUT"
    )
    parser.add_argument("paths", type=Path, nargs="+", help="DATASET OUT, or OUT with --others")
    args = parser.parse_args()
    if args.others:
        if len(args.paths) != 1:
            parser.error("--others takes one folder: OUT")
        other_meshes(args.paths[0])
    elif args.validation:
        if len(args.paths) != 2:
            parser.error("--validation takes FOLDER OUT")
        validation_meshes(*args.paths)
    else:
        if len(args.paths) != 2:
            parser.error("expected DATASET OUT")
        training_meshes(*args.paths, test=args.test)


if __name__ == "__main__":
    main()
