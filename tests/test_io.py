"""reconphys.io: atomic writes (no partial output, the old one intact), one permission rule,
validated JSON / NPZ reads with one-line errors."""

import json
import os
import stat

import numpy as np
import pytest

from reconphys.errors import InputError
from reconphys.io import (
    atomic_file,
    atomic_folder,
    check_new_output,
    file_mode,
    folder_mode,
    read_json,
    read_npz,
    remove_stale_staging,
    umask,
)


def _mode(path):
    return stat.S_IMODE(path.stat().st_mode)


def test_umask_is_read_without_changing_it():
    before = os.umask(0o027)
    try:
        assert umask() == 0o027
        assert file_mode() == 0o640 and folder_mode() == 0o750
        assert umask() == 0o027
    finally:
        os.umask(before)


def test_atomic_file_writes_with_the_umask_permissions(tmp_path):
    target = tmp_path / "sub" / "out.npz"
    with atomic_file(target) as tmp:
        assert tmp.parent == target.parent and tmp.suffix == ".npz" and tmp.name.startswith(".")
        np.savez(tmp, a=np.arange(3))  # keeps the name: it ends in .npz
    assert np.array_equal(np.load(target)["a"], np.arange(3))
    assert _mode(target) == file_mode()
    assert [p.name for p in target.parent.iterdir()] == ["out.npz"]


def test_failed_atomic_file_leaves_the_old_file_and_no_temporary(tmp_path):
    target = tmp_path / "out.txt"
    target.write_text("old")
    with pytest.raises(RuntimeError), atomic_file(target) as tmp:
        tmp.write_text("partial")
        raise RuntimeError("disk full")
    assert target.read_text() == "old"
    assert [p.name for p in tmp_path.iterdir()] == ["out.txt"]


def test_atomic_folder_refuses_replaces_and_sets_permissions(tmp_path):
    target = tmp_path / "out"
    with atomic_folder(target) as staging:
        (staging / "a.txt").write_text("1")
    assert (target / "a.txt").read_text() == "1" and _mode(target) == folder_mode()
    with pytest.raises(InputError, match="already exists"):
        with atomic_folder(target):
            pass
    with atomic_folder(target, overwrite=True) as staging:
        (staging / "b.txt").write_text("2")
    assert sorted(p.name for p in target.iterdir()) == ["b.txt"]
    assert [p.name for p in tmp_path.iterdir()] == ["out"]


def test_failed_atomic_folder_leaves_the_old_folder(tmp_path):
    target = tmp_path / "out"
    target.mkdir()
    (target / "old.txt").write_text("old")
    with pytest.raises(RuntimeError), atomic_folder(target, overwrite=True) as staging:
        (staging / "new.txt").write_text("partial")
        raise RuntimeError("killed")
    assert [p.name for p in target.iterdir()] == ["old.txt"]
    assert [p.name for p in tmp_path.iterdir()] == ["out"]
    with pytest.raises(RuntimeError), atomic_folder(tmp_path / "new") as staging:
        raise RuntimeError("killed")
    assert [p.name for p in tmp_path.iterdir()] == ["out"]


def test_remove_stale_staging(tmp_path):
    (tmp_path / ".out.staging-1-abcd").mkdir()
    (tmp_path / ".out.old-1-abcd").mkdir()
    (tmp_path / ".outer.staging-1-abcd").mkdir()
    remove_stale_staging(tmp_path / "out")
    assert [p.name for p in tmp_path.iterdir()] == [".outer.staging-1-abcd"]


def test_check_new_output(tmp_path):
    assert check_new_output(tmp_path / "new", overwrite=False) == tmp_path / "new"
    assert check_new_output(tmp_path, overwrite=True) == tmp_path
    with pytest.raises(InputError) as error:
        check_new_output(tmp_path, overwrite=False, field="--out")
    assert str(error.value) == f"{tmp_path} [--out]: already exists (use --overwrite to replace it)"


@pytest.mark.parametrize(
    "content, kwargs, message",
    [
        (None, {}, "file not found"),
        ("{not json", {}, "not valid JSON"),
        ("[1, 2]", {}, ": expected a JSON object"),
        ("[1, 2]", {"expected": "a camera"}, ": expected a camera"),
        ('{"format": "x"}', {"format": "y"}, "[format]: expected format 'y'"),
        ('{"format": "y", "version": 2}', {"format": "y", "version": 1}, "[version]: version 2"),
    ],
)
def test_bad_json_is_a_one_line_error_naming_the_file(tmp_path, content, kwargs, message):
    path = tmp_path / "a.json"
    if content is not None:
        path.write_text(content)
    with pytest.raises(InputError) as error:
        read_json(path, **kwargs)
    text = str(error.value)
    assert "\n" not in text and text.startswith(str(path)) and message in text


def test_good_json(tmp_path):
    path = tmp_path / "a.json"
    path.write_text(json.dumps({"format": "y", "version": 1, "k": [1]}))
    assert read_json(path, "y", 1)["k"] == [1]


def test_npz_reads_and_checks(tmp_path):
    path = tmp_path / "a.npz"
    np.savez(path, x=np.zeros((4, 3), np.float32), i=np.arange(4))
    assert set(read_npz(path)) == {"x", "i"}
    assert list(read_npz(path, ("i",))) == ["i"]
    assert read_npz(path, {"x": ("f", (None, 3)), "i": ("i", (4,))})["x"].shape == (4, 3)
    for names, message in [
        (("y",), "[y]: missing"),
        ({"x": ("i", (None, 3))}, "[x]: dtype float32, expected integer"),
        ({"x": ("f", (None, 2))}, "[x]: shape [4, 3], expected [*, 2]"),
    ]:
        with pytest.raises(InputError) as error:
            read_npz(path, names)
        assert str(error.value) == f"{path} {message}"
    np.savez(path, x=np.full(2, np.nan))
    with pytest.raises(InputError, match=r"\[x\]: contains NaN or inf"):
        read_npz(path, {"x": ("f", (2,))})


@pytest.mark.parametrize("content", [None, b"not a zip"])
def test_bad_npz_is_a_one_line_error(tmp_path, content):
    path = tmp_path / "a.npz"
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(InputError) as error:
        read_npz(path)
    text = str(error.value)
    assert "\n" not in text and text.startswith(str(path))
    assert ("file not found" if content is None else "not a readable .npz file") in text
