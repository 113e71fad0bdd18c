"""Read and write Gaussians in the standard 3DGS PLY layout (what common splat viewers open).

Vertex properties, all float32, binary little-endian, in this order:
``x, y, z`` (metres), ``nx, ny, nz`` (zeros, unused), ``f_dc_0..2`` (SH DC), ``f_rest_0..3R-1``
(only when higher SH bands are present), ``opacity`` (logit), ``scale_0..2`` (log of metres),
``rot_0..3`` (quaternion w, x, y, z, not necessarily unit).

``f_rest`` is channel-major as in the original 3DGS code: ``f_rest_{c·R + r}`` holds coefficient
r of colour channel c, i.e. ``sh_rest[n, r, c]`` with ``sh_rest`` shaped ``[N, R, 3]``.

The reader accepts what other 3DGS tools write: any property order, extra properties (ignored),
any numeric property type (converted to float32), binary little/big-endian or ASCII, and other
elements before or after ``vertex``. Implemented with numpy (structured arrays for reading), no
plyfile dependency.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import torch

from reconphys.assets.gaussians import Gaussians
from reconphys.errors import InputError
from reconphys.io import atomic_file

# PLY scalar type names (both spellings) → numpy type codes without byte order.
_PLY_TYPES = {
    "char": "i1",
    "int8": "i1",
    "uchar": "u1",
    "uint8": "u1",
    "short": "i2",
    "int16": "i2",
    "ushort": "u2",
    "uint16": "u2",
    "int": "i4",
    "int32": "i4",
    "uint": "u4",
    "uint32": "u4",
    "float": "f4",
    "float32": "f4",
    "double": "f8",
    "float64": "f8",
}
_FORMATS = {"binary_little_endian": "<", "binary_big_endian": ">", "ascii": None}

MEANS = ("x", "y", "z")
NORMALS = ("nx", "ny", "nz")
SH_DC = ("f_dc_0", "f_dc_1", "f_dc_2")
OPACITY = "opacity"
LOG_SCALES = ("scale_0", "scale_1", "scale_2")
QUATS = ("rot_0", "rot_1", "rot_2", "rot_3")
REQUIRED = (*MEANS, *SH_DC, OPACITY, *LOG_SCALES, *QUATS)
_MAX_HEADER_BYTES = 1 << 20


def _property_names(num_rest: int) -> list[str]:
    rest = [f"f_rest_{i}" for i in range(num_rest)]
    return [*MEANS, *NORMALS, *SH_DC, *rest, OPACITY, *LOG_SCALES, *QUATS]


# --- writing ---


def _as_float32(name: str, tensor: torch.Tensor, shape: tuple[int, ...]) -> np.ndarray:
    array = tensor.detach().to("cpu", torch.float32).numpy()
    if array.shape != shape:
        raise ValueError(f"write_ply: {name} has shape {list(array.shape)}, expected {list(shape)}")
    if not np.isfinite(array).all():
        raise ValueError(f"write_ply: {name} contains NaN or inf; refusing to write it")
    return array


def write_ply(path: str | os.PathLike, gaussians: Gaussians) -> None:
    """Write one (unbatched, ``[N, ...]``) set of Gaussians as a binary 3DGS PLY, atomically.

    Values are stored as float32, so a float32 ``Gaussians`` round-trips bit-exactly through
    ``read_ply``. The file appears complete or not at all: it is written to a temporary file in the
    same folder (created if missing) and renamed into place (:func:`reconphys.io.atomic_file`).
    Raises ``ValueError`` for batched or non-finite Gaussians (a file no reader would accept).
    """
    path = Path(path)
    if gaussians.means.dim() != 2:
        shape = list(gaussians.means.shape)
        raise ValueError(f"write_ply: expected unbatched Gaussians, means [N, 3], got {shape}")
    n = gaussians.means.shape[0]
    rest_columns = np.zeros((n, 0), dtype=np.float32)
    if gaussians.sh_rest is not None:
        r = gaussians.sh_rest.shape[1] if gaussians.sh_rest.dim() == 3 else -1
        sh_rest = _as_float32("sh_rest", gaussians.sh_rest, (n, r, 3))
        rest_columns = sh_rest.transpose(0, 2, 1).reshape(n, 3 * r)  # channel-major
    # Columns in the order of _property_names; every property is float32, so a plain [N, P]
    # little-endian float32 table has exactly the bytes of the PLY vertex records.
    table = np.concatenate(
        [
            _as_float32("means", gaussians.means, (n, 3)),
            np.zeros((n, 3), dtype=np.float32),  # nx, ny, nz
            _as_float32("sh0", gaussians.sh0, (n, 3)),
            rest_columns,
            _as_float32("opacity_logits", gaussians.opacity_logits, (n,))[:, None],
            _as_float32("log_scales", gaussians.log_scales, (n, 3)),
            _as_float32("quats", gaussians.quats, (n, 4)),
        ],
        axis=1,
    ).astype("<f4")
    names = _property_names(rest_columns.shape[1])
    header = "\n".join(
        [
            "ply",
            "format binary_little_endian 1.0",
            f"element vertex {n}",
            *(f"property float {name}" for name in names),
            "end_header",
        ]
    )
    with atomic_file(path) as temporary, open(temporary, "wb") as f:
        f.write(header.encode("ascii") + b"\n" + table.tobytes())
        f.flush()
        os.fsync(f.fileno())


# --- reading ---


class _Element:
    def __init__(self, name: str, count: int):
        self.name = name
        self.count = count
        self.properties: list[tuple[str, str]] = []  # (name, numpy type code)
        self.has_list = False


def _parse_header(raw: bytes, source: str) -> tuple[str, list[_Element], int]:
    """Return (format, elements, offset of the body) from the start of a PLY file."""

    def fail(message: str) -> InputError:
        return InputError(message, source=source, field="header")

    if not raw.startswith(b"ply"):
        raise fail("not a PLY file (it does not start with 'ply')")
    end = raw.find(b"\nend_header", 0, _MAX_HEADER_BYTES)
    if end < 0:
        raise fail("no 'end_header' line: not a PLY file or truncated header")
    end += 1  # start of the end_header line
    body_start = raw.find(b"\n", end)
    if body_start < 0:
        raise fail("truncated after 'end_header'")
    try:
        lines = raw[:end].decode("ascii").splitlines()
    except UnicodeDecodeError as e:
        raise fail("header is not ASCII text") from e

    file_format, elements = None, []
    for line in lines[1:]:
        words = line.split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "format":
            if len(words) != 3 or words[1] not in _FORMATS:
                raise fail(f"unsupported format line {line.strip()!r}")
            file_format = words[1]
        elif words[0] == "element":
            if len(words) != 3 or not words[2].isdigit():
                raise fail(f"malformed element line {line.strip()!r}")
            elements.append(_Element(words[1], int(words[2])))
        elif words[0] == "property":
            if not elements:
                raise fail("property declared before any element")
            if len(words) == 5 and words[1] == "list":
                elements[-1].has_list = True
                elements[-1].properties.append((words[4], "list"))
            elif len(words) == 3 and words[1] in _PLY_TYPES:
                if any(words[2] == name for name, _ in elements[-1].properties):
                    raise InputError("property declared twice", source=source, field=words[2])
                elements[-1].properties.append((words[2], _PLY_TYPES[words[1]]))
            else:
                raise fail(f"malformed property line {line.strip()!r}")
        else:
            raise fail(f"unknown header line {line.strip()!r}")
    if file_format is None:
        raise fail("missing 'format' line")
    return file_format, elements, body_start + 1


def _read_vertex_binary(
    raw: bytes, body_start: int, elements: list[_Element], byte_order: str, source: str
) -> np.ndarray:
    offset = body_start
    for element in elements:
        if element.has_list:
            raise InputError(
                "list properties before the vertex data are not supported in binary PLY",
                source=source,
                field=element.name,
            )
        dtype = np.dtype([(name, byte_order + code) for name, code in element.properties])
        if element.name == "vertex":
            needed = element.count * dtype.itemsize
            available = len(raw) - offset
            if available < needed:
                raise InputError(
                    f"truncated: {element.count} vertices need {needed} bytes, found {available}",
                    source=source,
                    field="vertex",
                )
            return np.frombuffer(raw, dtype=dtype, count=element.count, offset=offset)
        offset += element.count * dtype.itemsize
    raise AssertionError("unreachable: the vertex element was checked before")


def _read_vertex_ascii(
    raw: bytes, body_start: int, elements: list[_Element], source: str
) -> np.ndarray:
    lines = raw[body_start:].decode("ascii", errors="replace").splitlines()
    first = 0
    for element in elements:
        if element.name == "vertex":
            break
        first += element.count  # one line per item in ASCII PLY
    vertex = next(e for e in elements if e.name == "vertex")
    if vertex.has_list:
        raise InputError("list properties are not supported", source=source, field="vertex")
    rows = [line.split() for line in lines[first : first + vertex.count]]
    if len(rows) < vertex.count or any(len(row) < len(vertex.properties) for row in rows):
        raise InputError(
            f"truncated: expected {vertex.count} vertex lines of {len(vertex.properties)} values",
            source=source,
            field="vertex",
        )
    dtype = np.dtype([(name, code) for name, code in vertex.properties])
    data = np.empty(vertex.count, dtype=dtype)
    for column, (name, code) in enumerate(vertex.properties):
        try:
            values = np.array([row[column] for row in rows], dtype=np.float64)
        except ValueError as e:
            raise InputError("non-numeric value", source=source, field=name) from e
        data[name] = values.astype(code)
    return data


def _column(data: np.ndarray, name: str, source: str) -> np.ndarray:
    """One property as a float32 ``[N]`` array, finite."""
    values = np.asarray(data[name]).astype(np.float32)  # copies, native byte order
    if not np.isfinite(values).all():
        bad = int(np.flatnonzero(~np.isfinite(values))[0])
        raise InputError(f"non-finite value at vertex {bad}", source=source, field=name)
    return values


def _stack(data: np.ndarray, names: tuple[str, ...] | list[str], source: str) -> torch.Tensor:
    return torch.from_numpy(np.stack([_column(data, name, source) for name in names], axis=-1))


def read_ply(path: str | os.PathLike) -> Gaussians:
    """Read a 3DGS PLY into CPU float32 ``Gaussians`` ``[N, ...]`` (``sh_rest`` ``[N, R, 3]``).

    Raises ``InputError`` naming the file, and the property when one is at fault, for a missing
    file, a file that is not PLY, a missing required property, truncated data or NaN/inf values.
    """
    path = Path(path)
    source = str(path)
    if not path.is_file():
        raise InputError("file not found", source=source)
    raw = path.read_bytes()
    file_format, elements, body_start = _parse_header(raw, source)

    vertex = next((e for e in elements if e.name == "vertex"), None)
    if vertex is None:
        raise InputError("no 'element vertex' in the header", source=source, field="vertex")
    present = {name for name, _ in vertex.properties}
    for name in REQUIRED:
        if name not in present:
            raise InputError("required property missing", source=source, field=name)
    rest_indices = sorted(
        int(name[len("f_rest_") :])
        for name in present
        if name.startswith("f_rest_") and name[len("f_rest_") :].isdigit()
    )
    num_rest = len(rest_indices)
    if rest_indices != list(range(num_rest)):
        missing = sorted(set(range(max(rest_indices) + 1)) - set(rest_indices))[0]
        raise InputError(
            "property missing from the f_rest_* sequence", source=source, field=f"f_rest_{missing}"
        )
    if num_rest % 3 != 0:
        raise InputError(
            f"{num_rest} f_rest_* properties, expected a multiple of 3 (R coefficients × RGB)",
            source=source,
            field=f"f_rest_{num_rest - 1}",
        )

    byte_order = _FORMATS[file_format]
    if byte_order is None:
        data = _read_vertex_ascii(raw, body_start, elements, source)
    else:
        data = _read_vertex_binary(raw, body_start, elements, byte_order, source)

    sh_rest = None
    if num_rest:
        n, r = vertex.count, num_rest // 3
        flat = _stack(data, [f"f_rest_{i}" for i in range(num_rest)], source)  # [N, 3R]
        sh_rest = flat.reshape(n, 3, r).transpose(1, 2).contiguous()  # [N, R, 3]
    return Gaussians(
        means=_stack(data, MEANS, source),
        quats=_stack(data, QUATS, source),
        log_scales=_stack(data, LOG_SCALES, source),
        opacity_logits=torch.from_numpy(_column(data, OPACITY, source)),
        sh0=_stack(data, SH_DC, source),
        sh_rest=sh_rest,
    )
