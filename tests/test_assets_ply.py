"""3DGS PLY reader/writer: exact round trip, standard layout, foreign files, bad input."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from reconphys.assets.gaussians import Gaussians
from reconphys.assets.ply import read_ply, write_ply
from reconphys.errors import InputError

STANDARD_ORDER_NO_REST = (
    "x y z nx ny nz f_dc_0 f_dc_1 f_dc_2 opacity scale_0 scale_1 scale_2 rot_0 rot_1 rot_2 rot_3"
).split()


def random_gaussians(n: int = 64, rest: int | None = 15, seed: int = 0) -> Gaussians:
    g = torch.Generator().manual_seed(seed)

    def rand(*shape):  # wide dynamic range so that bit-exactness is really exercised
        return torch.randn(*shape, generator=g) * torch.exp(4 * torch.randn(*shape, generator=g))

    return Gaussians(
        means=rand(n, 3),
        quats=rand(n, 4),
        log_scales=rand(n, 3),
        opacity_logits=rand(n),
        sh0=rand(n, 3),
        sh_rest=None if rest is None else rand(n, rest, 3),
    )


def assert_bit_equal(a: torch.Tensor, b: torch.Tensor) -> None:
    assert a.dtype == b.dtype == torch.float32
    assert a.shape == b.shape
    assert torch.equal(a.view(torch.int32), b.view(torch.int32))


def header_and_body(path) -> tuple[list[str], bytes]:
    raw = path.read_bytes()
    end = raw.index(b"end_header\n") + len(b"end_header\n")
    return raw[:end].decode("ascii").splitlines(), raw[end:]


@pytest.mark.parametrize("rest", [None, 3, 15])
def test_round_trip_is_bit_exact(tmp_path, rest):
    original = random_gaussians(rest=rest)
    path = tmp_path / "g.ply"
    write_ply(path, original)
    loaded = read_ply(path)
    for name in ("means", "quats", "log_scales", "opacity_logits", "sh0"):
        assert_bit_equal(getattr(loaded, name), getattr(original, name))
    if rest is None:
        assert loaded.sh_rest is None
    else:
        assert_bit_equal(loaded.sh_rest, original.sh_rest)


def test_written_layout_is_standard_3dgs(tmp_path):
    """Header, property order, and channel-major f_rest, checked by decoding the bytes by hand."""
    n, r = 5, 3
    g = random_gaussians(n=n, rest=r)
    sh_rest = (100 * torch.arange(r).view(1, r, 1) + torch.arange(3).view(1, 1, 3)).float()
    g.sh_rest = sh_rest + 1000 * torch.arange(n).view(n, 1, 1)  # value = 1000 n + 100 r + c
    path = tmp_path / "g.ply"
    write_ply(path, g)

    header, body = header_and_body(path)
    rest_names = [f"f_rest_{i}" for i in range(3 * r)]
    names = [*STANDARD_ORDER_NO_REST[:9], *rest_names, *STANDARD_ORDER_NO_REST[9:]]
    assert header == [
        "ply",
        "format binary_little_endian 1.0",
        f"element vertex {n}",
        *(f"property float {name}" for name in names),
        "end_header",
    ]
    table = np.frombuffer(body, dtype="<f4").reshape(n, len(names))
    column = {name: table[:, i] for i, name in enumerate(names)}
    for c in range(3):
        for k in range(r):  # 3DGS: f_rest_{c·R + k} is coefficient k of channel c
            np.testing.assert_array_equal(column[f"f_rest_{c * r + k}"], g.sh_rest[:, k, c].numpy())
    np.testing.assert_array_equal(column["nx"], 0.0)
    np.testing.assert_array_equal(column["opacity"], g.opacity_logits.numpy())
    np.testing.assert_array_equal(column["rot_0"], g.quats[:, 0].numpy())  # w first
    np.testing.assert_array_equal(column["scale_2"], g.log_scales[:, 2].numpy())


def write_foreign_ply(path, n: int = 7, seed: int = 1, order: str = "<") -> dict[str, np.ndarray]:
    """A PLY as another tool might write it: shuffled order, float64, extra properties, an extra
    element before and one after the vertices. Returns the values written, by property name."""
    rng = np.random.default_rng(seed)
    fields = [
        ("rot_2", "<f4"),
        ("x", "<f8"),
        ("opacity", "<f8"),
        ("f_dc_1", "<f4"),
        ("scale_0", "<f4"),
        ("y", "<f8"),
        ("rot_0", "<f4"),
        ("f_dc_0", "<f4"),
        ("confidence", "<f4"),  # extra, must be ignored
        ("scale_2", "<f4"),
        ("z", "<f8"),
        ("rot_3", "<f4"),
        ("f_dc_2", "<f4"),
        ("segment", "u1"),  # extra integer property
        ("scale_1", "<f4"),
        ("rot_1", "<f4"),
    ]
    fields = [(name, t.replace("<", order)) for name, t in fields]
    data = np.zeros(n, dtype=np.dtype(fields))
    for name, _ in fields:
        data[name] = rng.integers(0, 200, n) if name == "segment" else rng.normal(size=n)
    ply_types = {"f4": "float", "f8": "double", "u1": "uchar"}
    file_format = {"<": "binary_little_endian", ">": "binary_big_endian"}[order]
    header = (
        ["ply", f"format {file_format} 1.0", "comment written by some other tool"]
        + ["element extrinsic 2", "property double tx", "property uchar flag"]
        + [f"element vertex {n}"]
        + [f"property {ply_types[t.lstrip('<>')]} {name}" for name, t in fields]
        + ["element camera 1", "property float fx", "end_header"]
    )
    leading = np.zeros(2, dtype=[("tx", order + "f8"), ("flag", "u1")])
    trailing = np.array([500], dtype=order + "f4")
    payload = leading.tobytes() + data.tobytes() + trailing.tobytes()
    path.write_bytes(("\n".join(header) + "\n").encode() + payload)
    return {name: data[name] for name, _ in fields}


@pytest.mark.parametrize("order", ["<", ">"])
def test_reads_foreign_property_order_extra_properties_and_float64(tmp_path, order):
    path = tmp_path / "foreign.ply"
    values = write_foreign_ply(path, order=order)
    g = read_ply(path)
    assert g.sh_rest is None
    for tensor in (g.means, g.quats, g.log_scales, g.opacity_logits, g.sh0):
        assert tensor.dtype == torch.float32
    f32 = {name: v.astype(np.float32) for name, v in values.items()}
    np.testing.assert_array_equal(g.means.numpy(), np.stack([f32["x"], f32["y"], f32["z"]], -1))
    np.testing.assert_array_equal(g.quats[:, 0].numpy(), f32["rot_0"])
    np.testing.assert_array_equal(g.quats[:, 3].numpy(), f32["rot_3"])
    np.testing.assert_array_equal(g.log_scales[:, 1].numpy(), f32["scale_1"])
    np.testing.assert_array_equal(g.opacity_logits.numpy(), f32["opacity"])
    np.testing.assert_array_equal(g.sh0[:, 2].numpy(), f32["f_dc_2"])


def test_reads_ascii_ply(tmp_path):
    names = ["x", "y", "z", "f_dc_0", "f_dc_1", "f_dc_2", "opacity"]
    names += ["scale_0", "scale_1", "scale_2", "rot_0", "rot_1", "rot_2", "rot_3"]
    rows = [[i + 0.25 * k for k in range(len(names))] for i in range(3)]
    text = "\n".join(
        ["ply", "format ascii 1.0", "element vertex 3"]
        + [f"property float {name}" for name in names]
        + ["end_header"]
        + [" ".join(str(v) for v in row) for row in rows]
    )
    path = tmp_path / "ascii.ply"
    path.write_text(text + "\n")
    g = read_ply(path)
    np.testing.assert_array_equal(g.means[1].numpy(), np.float32([1.0, 1.25, 1.5]))
    np.testing.assert_array_equal(g.quats[2].numpy(), np.float32([2 + 2.5, 2 + 2.75, 5.0, 5.25]))


def test_write_is_atomic_and_overwrites(tmp_path):
    path = tmp_path / "sub" / "g.ply"
    write_ply(path, random_gaussians(n=4, rest=None, seed=0))
    write_ply(path, random_gaussians(n=9, rest=None, seed=1))
    assert read_ply(path).num_gaussians == 9
    assert [p.name for p in path.parent.iterdir()] == ["g.ply"]  # no temporary left behind

    bad = random_gaussians(n=3, rest=None)
    bad.log_scales[1, 0] = float("nan")
    with pytest.raises(ValueError, match="log_scales"):
        write_ply(path, bad)
    assert read_ply(path).num_gaussians == 9  # the previous file is untouched
    assert [p.name for p in path.parent.iterdir()] == ["g.ply"]


def test_rejects_batched_gaussians(tmp_path):
    g = random_gaussians(n=4, rest=None)
    batched = g.map(lambda t: t.unsqueeze(0))
    with pytest.raises(ValueError, match="unbatched"):
        write_ply(tmp_path / "g.ply", batched)


def _standard_file(tmp_path, name="bad.ply"):
    path = tmp_path / name
    write_ply(path, random_gaussians(n=6, rest=3))
    return path


def _replace_in_header(path, old: str, new: str) -> None:
    raw = path.read_bytes()
    end = raw.index(b"end_header")
    path.write_bytes(raw[:end].replace(old.encode(), new.encode()) + raw[end:])


def _set_value(path, vertex: int, property_name: str, value: float) -> None:
    header, body = header_and_body(path)
    names = [line.split()[-1] for line in header if line.startswith("property")]
    table = np.frombuffer(body, dtype="<f4").reshape(-1, len(names)).copy()
    table[vertex, names.index(property_name)] = value
    raw = path.read_bytes()
    path.write_bytes(raw[: len(raw) - len(body)] + table.tobytes())


def _expect_error(path, field: str | None):
    with pytest.raises(InputError) as info:
        read_ply(path)
    message = str(info.value)
    assert path.name in message
    assert "\n" not in message
    if field is not None:
        assert field in message
        assert info.value.field == field
    return message


def test_missing_file(tmp_path):
    _expect_error(tmp_path / "nothing_here.ply", None)


def test_not_a_ply(tmp_path):
    path = tmp_path / "notes.ply"
    path.write_text("hello, I am not a point cloud\n")
    _expect_error(path, "header")
    path.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 3\n")  # no end_header
    _expect_error(path, "header")


@pytest.mark.parametrize("field", ["opacity", "scale_1", "rot_0", "x", "f_dc_2"])
def test_missing_required_property(tmp_path, field):
    path = _standard_file(tmp_path)
    _replace_in_header(path, f"property float {field}\n", "property float renamed_away\n")
    _expect_error(path, field)


def test_missing_f_rest_entry(tmp_path):
    path = _standard_file(tmp_path)
    _replace_in_header(path, "property float f_rest_4\n", "property float unrelated\n")
    _expect_error(path, "f_rest_4")


def test_truncated_data(tmp_path):
    path = _standard_file(tmp_path)
    raw = path.read_bytes()
    path.write_bytes(raw[:-10])
    message = _expect_error(path, "vertex")
    assert "truncated" in message


@pytest.mark.parametrize("value", [float("nan"), float("inf"), -float("inf")])
@pytest.mark.parametrize("field", ["scale_1", "opacity", "y", "f_rest_5"])
def test_non_finite_values(tmp_path, field, value):
    path = _standard_file(tmp_path)
    _set_value(path, 3, field, value)
    message = _expect_error(path, field)
    assert "vertex 3" in message
