"""Objaverse (1.0) objects from a local mirror, optionally filled by downloading (network).

The mirror has the layout the ``objaverse`` package writes (``~/.objaverse/hf-objaverse-v1``)::

    ROOT/object-paths.json.gz     {uid: "glbs/000-023/<uid>.glb", ...} (gzip JSON)
    ROOT/glbs/000-023/<uid>.glb

Candidates are the UIDs of ``object-paths.json.gz`` (or of a UID list file, one a line, e.g. a
filtered selection like the paper's 500 objects) whose .glb is present locally. Nothing touches the
network unless ``download=True`` (``make-data --download``): then the index and the missing .glb
files of the drawn objects are fetched from the Hugging Face mirror of Objaverse 1.0.
"""

from __future__ import annotations

import gzip
import json
import os
import shutil
import urllib.request
from pathlib import Path

from ..errors import InputError
from ..io import atomic_file
from .settings import DataSettings
from .source_base import ObjectRef, load_file_object

DEFAULT_ROOT = Path("~/.objaverse/hf-objaverse-v1").expanduser()
BASE_URL = "https://huggingface.co/datasets/allenai/objaverse/resolve/main"
INDEX = "object-paths.json.gz"
PREFIX = "objaverse/"


def _download(url: str, target: Path) -> None:
    """Fetch ``url`` into ``target`` atomically (a killed download leaves no partial file)."""
    try:
        with atomic_file(target) as tmp, open(tmp, "wb") as out:
            with urllib.request.urlopen(url, timeout=60) as response:
                shutil.copyfileobj(response, out)
    except OSError as e:
        raise InputError(f"download failed ({e})", source=url) from None


class ObjaverseSource:
    """Objaverse 1.0 objects (.glb) by UID; ids are ``objaverse/<uid>``."""

    name = "objaverse"

    def __init__(
        self,
        root: str | os.PathLike | None = None,
        uids_file: str | os.PathLike | None = None,
        download: bool = False,
    ):
        self.root = Path(root).expanduser() if root else DEFAULT_ROOT
        self.download = download
        index_path = self.root / INDEX
        if not index_path.is_file():
            if not download:
                raise InputError(
                    f"no {INDEX}: not an Objaverse mirror (give --objaverse-root, or --download "
                    "to fetch objects; that needs network access)",
                    source=str(self.root),
                )
            _download(f"{BASE_URL}/{INDEX}", index_path)
        try:
            with gzip.open(index_path, "rt") as f:
                self.paths: dict[str, str] = json.load(f)
        except (OSError, EOFError, json.JSONDecodeError) as e:
            raise InputError(
                f"not a readable gzip JSON index ({e})", source=str(index_path)
            ) from None
        if not isinstance(self.paths, dict):
            raise InputError("expected a JSON object {uid: path}", source=str(index_path))
        self.uids = sorted(self.paths)
        if uids_file:
            try:
                wanted = [u.strip() for u in Path(uids_file).read_text().splitlines() if u.strip()]
            except OSError as e:
                raise InputError(f"cannot read ({e.strerror})", source=str(uids_file)) from None
            missing = [u for u in wanted if u not in self.paths]
            if missing:
                raise InputError(
                    f"{len(missing)} UIDs not in {INDEX}, e.g. {missing[0]}", str(uids_file)
                )
            self.uids = sorted(set(wanted))

    def local_path(self, uid: str) -> Path:
        return self.root / self.paths[uid]

    def candidates(self, count: int) -> list[ObjectRef]:
        """UIDs with a local .glb (all listed UIDs when downloading is allowed)."""
        uids = (
            self.uids if self.download else [u for u in self.uids if self.local_path(u).is_file()]
        )
        if not uids:
            raise InputError(
                "no .glb objects found in the mirror (use --download to fetch them)",
                source=str(self.root),
            )
        return [ObjectRef(PREFIX + u, str(self.local_path(u))) for u in uids]

    def describe(self, ref: ObjectRef) -> dict:
        uid = ref.id.removeprefix(PREFIX)
        return {"uid": uid, "file": self.paths.get(uid, "")}

    def load(self, ref: ObjectRef, settings: DataSettings):
        path = Path(ref.path)
        if not path.is_file() and self.download:
            _download(f"{BASE_URL}/{self.paths[ref.id.removeprefix(PREFIX)]}", path)
        return load_file_object(path, ref.id, settings)
