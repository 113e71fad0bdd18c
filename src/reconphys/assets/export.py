"""Exporting an asset to other simulators (docs/export.md).

- :func:`export_newton`: one ``.npz`` of particles and springs in SI units, laid out like the
  particle/spring arrays of NVIDIA Warp's ``warp.sim`` and Newton's ``ModelBuilder``
  (``particle_q``, ``particle_qd``, ``particle_mass``, ``spring_indices``, ``spring_rest_length``,
  ``spring_ke``, ``spring_kd``), plus the Gaussians and their binding.
- :func:`export_mjcf`: a MuJoCo MJCF file with the anchors as the vertices of a one-dimensional
  ``flexcomp`` and the springs as its edges, on a ground plane.

Both engines use linear springs, ``F = ke (L − l) + kd (v_rel · u)``. Ours is
``F = k ε (1 + |ε|)^p_k + (d / l) (v_rel · u)`` with ``ε = L / l − 1``
(docs/design.md#physical-model), so per spring
``ke = k / l`` (N/m) — exact for ``p_k = 0`` and the small-strain tangent otherwise — and
``kd = d / l`` (N·s/m). :func:`spring_coefficients` forms them from the simulator's own model.

Both writers are atomic: the file is written under a temporary name beside the target and renamed
into place, so a failed export leaves no partial file.
"""

from __future__ import annotations

import io
import os
import xml.etree.ElementTree as ET
from collections.abc import Callable
from pathlib import Path

import numpy as np
import torch

from ..errors import InputError
from ..io import atomic_file
from ..names import EXPORT_FORMATS
from .asset import Asset

NEWTON_FORMAT = "reconphys.newton"
NEWTON_VERSION = 1
# Collision radius of the MuJoCo flex vertices (metres). Our anchors are points on the plane
# z = ground_height; a small sphere keeps the resting height within this much of ours.
MJCF_VERTEX_RADIUS = 0.002


def spring_coefficients(asset: Asset) -> tuple[np.ndarray, np.ndarray]:
    """Linear spring and dashpot constants per spring, as our simulator forms them.

    Returns ``ke [E]`` = k / l in N/m and ``kd [E]`` = d / l in N·s/m (float64), from the
    simulator's :class:`~reconphys.physics.SpringMassModel` of the asset (so per-spring
    ``stiffness`` / ``damping`` arrays of ``anchors.npz`` override the scalars of physics.json).
    ``ke`` is the exact constant for ``spring_exponent = 0`` and the small-strain tangent
    stiffness of ``k ε (1 + |ε|)^p_k`` otherwise.
    """
    model = asset.model(dtype=torch.float64)
    num_springs = model.num_springs
    rest = model.rest_length  # [E] metres
    ke = (model.stiffness / rest).expand(1, num_springs)[0]  # [1, E|1] / [E] → [E]
    kd = (model.damping / rest).expand(1, num_springs)[0]
    return ke.numpy().copy(), kd.numpy().copy()


def per_anchor(asset: Asset, name: str) -> np.ndarray:
    """``mass`` (kg) or ``friction`` per anchor, ``[N_A]`` float64 (the scalar broadcast)."""
    value = asset.attribute(name).double()[0]  # [N_A] or [1]
    return value.expand(asset.num_anchors).numpy().copy()


def substeps_used(asset: Asset) -> int:
    """Substeps per frame that ``reconphys simulate`` uses for this asset: the stability bound
    of :func:`~reconphys.physics.stable_substeps`, never below the asset's ``substeps``."""
    from ..physics import stable_substeps

    p = asset.physics
    return stable_substeps(asset.model(), asset.initial_state().x, p.frame_dt, p.substeps)


def _write_atomically(path: Path, write: Callable[[io.BufferedWriter], None]) -> Path:
    """Write through ``write(file)`` to a temporary file beside ``path``, then rename it."""
    path = Path(path)
    if path.is_dir():
        raise InputError("is a folder, expected a file name", source=str(path))
    with atomic_file(path) as tmp, open(tmp, "wb") as f:
        write(f)
    return path


# ----------------------------------------------------------------------------------------------
# NVIDIA Warp / Newton


def newton_arrays(asset: Asset) -> dict[str, np.ndarray]:
    """The arrays :func:`export_newton` writes (see docs/export.md for the table)."""
    p = asset.physics
    ke, kd = spring_coefficients(asset)
    friction = per_anchor(asset, "friction")
    substeps = substeps_used(asset)
    return {
        "format": np.array(NEWTON_FORMAT),
        "version": np.int64(NEWTON_VERSION),
        "particle_q": asset.x0.detach().cpu().float().numpy(),  # [N_A, 3] m
        "particle_qd": asset.v0.detach().cpu().float().numpy(),  # [N_A, 3] m/s
        "particle_mass": per_anchor(asset, "mass").astype(np.float32),  # [N_A] kg
        "particle_friction": friction.astype(np.float32),  # [N_A]
        "spring_indices": asset.springs.detach().cpu().numpy().astype(np.int32),  # [E, 2]
        "spring_rest_length": asset.rest_length.detach().cpu().float().numpy(),  # [E] m
        "spring_ke": ke.astype(np.float32),  # [E] N/m
        "spring_kd": kd.astype(np.float32),  # [E] N·s/m
        "spring_exponent": np.float64(p.spring_exponent),
        "ground_friction": np.float64(friction.mean()),
        "ground_height": np.float64(p.ground_height),
        "restitution": np.float64(p.restitution),
        "gravity": np.asarray(p.gravity, dtype=np.float64),  # [3] m/s²
        "frame_dt": np.float64(p.frame_dt),  # s
        "substeps": np.int64(substeps),
        "gaussian_means": asset.gaussians.means.detach().cpu().float().numpy(),  # [N, 3] m
        "binding_index": asset.binding_index.detach().cpu().numpy().astype(np.int32),
        "binding_weight": asset.binding_weight.detach().cpu().float().numpy(),
    }


def export_newton(asset: Asset, path: str | os.PathLike) -> Path:
    """Write the asset as one ``.npz`` for NVIDIA Warp / Newton's particle + spring model.

    Units SI. Springs carry ``spring_ke = k / l`` (N/m) and ``spring_kd = d / l`` (N·s/m) per
    spring, from :func:`spring_coefficients`; ``spring_exponent`` is kept for the record (the
    other engines' springs are linear). Written atomically.
    """
    arrays = newton_arrays(asset)
    return _write_atomically(Path(path), lambda f: np.savez(f, **arrays))


# ----------------------------------------------------------------------------------------------
# MuJoCo MJCF


def _numbers(values, fmt: str = "{:.9g}") -> str:  # 9 digits round-trip float32
    return " ".join(fmt.format(float(v)) for v in np.asarray(values).reshape(-1))


def _spread(values: np.ndarray) -> str:
    return f"[{values.min():.4g}, {values.max():.4g}]"


def mjcf_document(asset: Asset) -> str:
    """The MJCF text of :func:`export_mjcf` (a comment listing what does not map, then XML)."""
    p = asset.physics
    ke, kd = spring_coefficients(asset)
    mass = per_anchor(asset, "mass")
    friction = per_anchor(asset, "friction")
    substeps = substeps_used(asset)
    timestep = p.frame_dt / substeps
    x0 = asset.x0.detach().cpu().double().numpy()
    springs = asset.springs.detach().cpu().numpy()
    rest = asset.rest_length.detach().cpu().double().numpy()
    initial_length = np.linalg.norm(x0[springs[:, 1]] - x0[springs[:, 0]], axis=1)
    rest_mismatch = float(np.abs(initial_length - rest).max()) if len(rest) else 0.0
    edge_ke, edge_kd = float(np.median(ke)), float(np.median(kd))
    mu = float(friction.mean())
    stiffening = (1.1**p.spring_exponent - 1.0) * 100.0

    notes = [
        f"reconphys asset {p.object_id or '(no id)'} as a MuJoCo flex: {asset.num_anchors} "
        f"anchors as vertices, {len(springs)} springs as edges. SI units, z up.",
        "What maps: anchor positions (point), springs (element), total mass, gravity, ground "
        "plane height and friction, substep length (timestep = frame_dt / substeps = "
        f"{p.frame_dt:g} / {substeps}), initial velocities (keyframe 'initial': "
        "mj_resetDataKeyframe(model, data, 0)).",
        "What does not map:",
        f"- Edge stiffness and damping: MuJoCo has one value for all edges of a flex; ours are "
        f"per spring, k/l and d/l, because they scale with the rest length l. Chosen: the "
        f"medians, stiffness {edge_ke:.6g} N/m (ours: {_spread(ke)}), damping "
        f"{edge_kd:.6g} N s/m (ours: {_spread(kd)}).",
        f"- Spring law: MuJoCo edges are linear; ours is k eps (1 + |eps|)^p_k with p_k = "
        f"{p.spring_exponent:g}, so the stiffness above is the small-strain value (ours is "
        f"{stiffening:.3g} % stiffer at 10 % strain).",
        f"- Rest lengths: MuJoCo takes them from the initial vertex positions; they differ "
        f"from anchors.npz rest_length by at most {rest_mismatch:.3g} m.",
        f"- Mass: flexcomp spreads its mass evenly over the vertices; total {mass.sum():.6g} kg "
        f"(ours per anchor: {_spread(mass)} kg).",
        f"- Ground: MuJoCo soft contacts (solref, friction cone, vertices as spheres of "
        f"radius {MJCF_VERTEX_RADIUS:g} m) instead of our projection onto the plane with "
        f"velocity-level Coulomb friction; friction {mu:.4g} (ours per anchor: "
        f"{_spread(friction)}); restitution {p.restitution:g} is not mapped (MuJoCo contacts "
        "are close to inelastic with the default solref).",
        "- Appearance: the Gaussians are not part of this file; move them with the asset's "
        "binding.npz from data.flexvert_xpos (mu_t = mu_0 + sum w (x_t - x_0)).",
    ]
    comment = "\n".join(notes).replace("--", "- -")

    root = ET.Element("mujoco", model=f"reconphys-{p.object_id or 'asset'}")
    ET.SubElement(
        root,
        "option",
        timestep=f"{timestep:.9g}",
        gravity=_numbers(p.gravity),
    )
    world = ET.SubElement(root, "worldbody")
    ET.SubElement(
        world,
        "geom",
        name="ground",
        type="plane",
        pos=_numbers([0.0, 0.0, p.ground_height]),
        size="0 0 1",
        friction=f"{mu:.7g} 0.005 0.0001",
    )
    flex = ET.SubElement(
        world,
        "flexcomp",
        name="object",
        type="direct",
        dim="1",
        mass=f"{mass.sum():.9g}",
        radius=f"{MJCF_VERTEX_RADIUS:g}",
        point=_numbers(x0),
        element=" ".join(str(int(i)) for i in springs.reshape(-1)),
    )
    ET.SubElement(flex, "edge", stiffness=f"{edge_ke:.9g}", damping=f"{edge_kd:.9g}")
    ET.SubElement(flex, "contact", condim="3", friction=f"{mu:.7g}", selfcollide="none")
    keyframe = ET.SubElement(root, "keyframe")
    v0 = asset.v0.detach().cpu().double().numpy()
    ET.SubElement(keyframe, "key", name="initial", qvel=_numbers(v0))
    ET.indent(root)
    return f"<!--\n{comment}\n-->\n" + ET.tostring(root, encoding="unicode") + "\n"


def export_mjcf(asset: Asset, path: str | os.PathLike) -> Path:
    """Write the asset as a MuJoCo MJCF file: a ``flexcomp`` of type ``direct``, ``dim="1"``
    (anchors → vertices, springs → edges) on a ground plane. A comment at the top of the file
    lists what does not map. Written atomically."""
    text = mjcf_document(asset)
    return _write_atomically(Path(path), lambda f: f.write(text.encode("utf-8")))


EXPORTERS = {"newton": export_newton, "mjcf": export_mjcf}


def export_asset(asset: Asset, path: str | os.PathLike, format: str) -> Path:
    """Export ``asset`` to ``path`` in ``format`` (one of
    :data:`~reconphys.names.EXPORT_FORMATS`)."""
    if format not in EXPORTERS:
        raise InputError(
            f"expected one of {', '.join(EXPORT_FORMATS)}, got {format!r}", field="--format"
        )
    return EXPORTERS[format](asset, path)
