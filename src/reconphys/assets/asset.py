"""The asset folder (docs/design.md#asset-format): Gaussians + anchors + springs + binding +
physical attributes.

Layout::

    ASSET_DIR/
      gaussians.ply   standard 3DGS PLY
      anchors.npz     x0, v0 [N_A, 3] float32; springs [E, 2] int64; rest_length [E] float32;
                      optional per-anchor mass / friction [N_A], per-spring stiffness / damping [E]
      binding.npz     index [N, n_b] int64; weight [N, n_b] float32
      physics.json    attributes, integration settings, binding settings, derived SI figures

Every reader validates shapes, dtypes, index ranges and finiteness and raises
:class:`~reconphys.errors.InputError` naming the file and field. Writing is atomic: the folder is
assembled under a temporary name next to the target and renamed into place.
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from ..errors import InputError
from ..io import atomic_folder, check_array, check_number, read_json, read_npz
from ..physics import GRAVITY, SpringMassModel, State, Trajectory, deform_means, rollout
from .gaussians import Gaussians
from .ply import read_ply, write_ply

FORMAT = "reconphys.asset"
VERSION = 1
FILES = ("gaussians.ply", "anchors.npz", "binding.npz", "physics.json")
PER_ANCHOR_ARRAYS = ("mass", "friction")
PER_SPRING_ARRAYS = ("stiffness", "damping")


@dataclass
class PhysicsSettings:
    """The contents of physics.json (SI units)."""

    mass: float = 1.0  # kg per anchor
    stiffness: float = 300.0  # N per unit strain (spring constant k / l in N/m)
    damping: float = 1.0  # N·s per unit strain rate (dashpot d / l in N·s/m)
    friction: float = 0.5  # Coulomb coefficient
    spring_exponent: float = 0.5  # p_k
    restitution: float = 0.0  # e
    frame_dt: float = 0.03  # s
    substeps: int = 100  # minimum substeps per frame; more are used when stability needs them
    gravity: tuple[float, float, float] = GRAVITY  # m/s²
    ground_height: float = 0.0  # m
    num_anchors: int = 2048  # N_A
    num_neighbors: int = 32  # K of the kNN springs
    binding_neighbors: int = 16  # n_b
    binding_power: float = 2.0  # p_b
    object_id: str = ""  # seeds the anchor sampling

    @classmethod
    def from_data_settings(
        cls,
        data,  # a dataset's settings: DataSettings, its dict (model.json) or similar
        attributes: Mapping[str, float] | None = None,  # mass, stiffness, damping, friction
        object_id: str = "",
        **overrides,  # fields set explicitly (frame_dt, ground_height, num_anchors); None: skip
    ) -> PhysicsSettings:
        """The settings of an asset built from new Gaussians: the attributes, and the spring-mass
        settings of a dataset (anchors, springs, binding, contact, ``min_substeps`` → substeps,
        frame_dt). A setting the data does not name keeps this class's default; values are
        converted to the field's type."""
        get = data.get if isinstance(data, Mapping) else lambda key: getattr(data, key, None)
        values = {}
        for name, key in _DATA_SETTINGS.items():
            value = get(key)
            if value is not None:
                values[name] = type(getattr(cls, name))(value)
        values.update({k: v for k, v in overrides.items() if v is not None})
        return cls(**(attributes or {}), **values, object_id=object_id)


# PhysicsSettings field ← the name in a dataset's settings (DataSettings)
_DATA_SETTINGS = {
    "num_anchors": "num_anchors",
    "num_neighbors": "num_neighbors",
    "binding_neighbors": "binding_neighbors",
    "binding_power": "binding_power",
    "spring_exponent": "spring_exponent",
    "restitution": "restitution",
    "substeps": "min_substeps",
    "frame_dt": "frame_dt",
}


@dataclass
class Asset:
    gaussians: Gaussians  # N Gaussians at rest, world frame
    x0: Tensor  # [N_A, 3] initial anchor positions, metres
    v0: Tensor  # [N_A, 3] initial anchor velocities, m/s
    springs: Tensor  # [E, 2] int64
    rest_length: Tensor  # [E] metres
    binding_index: Tensor  # [N, n_b] int64
    binding_weight: Tensor  # [N, n_b]
    physics: PhysicsSettings = field(default_factory=PhysicsSettings)
    per_element: dict[str, Tensor] = field(default_factory=dict)  # optional mass/friction [N_A],
    # stiffness/damping [E] overriding the scalar values of physics.json

    @property
    def num_anchors(self) -> int:
        return self.x0.shape[0]

    def attribute(self, name: str) -> Tensor:
        """The attribute as the simulator takes it: [1, N_A|E] when per element, else [1]."""
        if name in self.per_element:
            return self.per_element[name].float()[None]
        return torch.tensor([float(getattr(self.physics, name))])

    def model(self, device=None, dtype: torch.dtype = torch.float32) -> SpringMassModel:
        """A batch-of-one simulator model on ``device``."""
        p = self.physics
        return SpringMassModel(
            springs=self.springs.to(device),
            rest_length=self.rest_length.to(device),
            mass=self.attribute("mass").to(device),
            stiffness=self.attribute("stiffness").to(device),
            damping=self.attribute("damping").to(device),
            friction=self.attribute("friction").to(device),
            spring_exponent=p.spring_exponent,
            restitution=p.restitution,
            gravity=tuple(p.gravity),
            ground_height=p.ground_height,
            dtype=dtype,
        )

    def initial_state(self, device=None, dtype: torch.dtype = torch.float32) -> State:
        return State(self.x0[None].to(device, dtype), self.v0[None].to(device, dtype))

    def simulate(
        self, frames: int, device: torch.device | str = "cpu", progress: bool = False
    ) -> Trajectory:
        """Roll the spring-mass system forward ``frames`` frames from the initial state, exactly
        as ``reconphys simulate`` does (float32, the asset's substeps raised to the stability
        bound; ``progress`` shows a progress bar).

        Returns a :class:`~reconphys.physics.Trajectory`: ``x``, ``v [1, frames+1, N_A, 3]`` (m,
        m/s; frame 0 is the initial state), ``substeps`` and ``frame_dt`` (s). Raises
        :class:`~reconphys.errors.InputError` if the result is not finite. On CPU, call
        ``torch.set_flush_denormal(True)`` first for speed (docs/physics.md).
        """
        if int(frames) < 1:
            raise InputError(f"must be ≥ 1, got {frames}", field="frames")
        device = torch.device(device)
        model = self.model(device)
        state = self.initial_state(device)
        with torch.no_grad():
            trajectory = rollout(
                model,
                state,
                int(frames),
                frame_dt=self.physics.frame_dt,
                min_substeps=self.physics.substeps,
                progress=progress,
            )
        if not torch.isfinite(trajectory.x).all():
            raise InputError("simulation produced NaN: the attributes are unstable")
        return trajectory

    def gaussian_means(
        self,
        anchors: Tensor,  # [..., N_A, 3] anchor positions (e.g. per frame [T, N_A, 3]), metres
    ) -> Tensor:  # [..., N, 3] metres, on anchors' device
        """Gaussian centres following the anchors through the asset's binding
        (docs/design.md#physical-model)."""
        device = anchors.device
        return deform_means(
            self.gaussians.means.to(device),
            self.x0.to(device),
            anchors,
            self.binding_index.to(device),
            self.binding_weight.to(device),
        )

    def total_mass(self) -> float:
        if "mass" in self.per_element:
            return float(self.per_element["mass"].double().sum())
        return self.physics.mass * self.num_anchors


def derived_figures(asset: Asset) -> dict:
    """Human-readable SI figures written beside the attributes (informative; never read back)."""
    k = asset.attribute("stiffness").double()[0]
    d = asset.attribute("damping").double()[0]
    length = asset.rest_length.double()
    spring_constant = k / length
    dashpot_constant = d / length
    return {
        "total_mass_kg": asset.total_mass(),
        "spring_constant_n_per_m": [float(spring_constant.min()), float(spring_constant.max())],
        "dashpot_constant_ns_per_m": [float(dashpot_constant.min()), float(dashpot_constant.max())],
        "rest_length_m": [float(length.min()), float(length.max())],
        "num_springs": int(asset.springs.shape[0]),
        "num_gaussians": int(asset.gaussians.num_gaussians),
        "units": "SI (m, s, kg); mass is per anchor; z up; ground at ground_height",
    }


# ----------------------------------------------------------------------------------------------
# writing


def write_asset(
    asset: Asset,
    folder: str | os.PathLike,
    overwrite: bool = False,
    notes: dict | None = None,  # extra keys of physics.json (predict: the intervals); not read
) -> Path:
    """Write ``asset`` to ``folder`` atomically; refuses an existing folder unless ``overwrite``."""
    folder = Path(folder)
    validate_asset(asset, str(folder))
    with atomic_folder(folder, overwrite) as staging:
        write_ply(staging / "gaussians.ply", asset.gaussians)
        anchors = {
            "x0": asset.x0.detach().cpu().float().numpy(),
            "v0": asset.v0.detach().cpu().float().numpy(),
            "springs": asset.springs.detach().cpu().to(torch.int64).numpy(),
            "rest_length": asset.rest_length.detach().cpu().float().numpy(),
        }
        anchors.update({k: v.detach().cpu().float().numpy() for k, v in asset.per_element.items()})
        np.savez(staging / "anchors.npz", **anchors)
        np.savez(
            staging / "binding.npz",
            index=asset.binding_index.detach().cpu().to(torch.int64).numpy(),
            weight=asset.binding_weight.detach().cpu().float().numpy(),
        )
        physics = {"format": FORMAT, "version": VERSION}
        physics.update({k: v for k, v in vars(asset.physics).items()})
        physics["gravity"] = [float(g) for g in asset.physics.gravity]
        physics["derived"] = derived_figures(asset)
        physics.update(notes or {})
        with open(staging / "physics.json", "w") as f:
            json.dump(physics, f, indent=2)
            f.write("\n")
    return folder


# ----------------------------------------------------------------------------------------------
# reading and validation


def _read_physics(path: Path) -> PhysicsSettings:
    physics = read_json(path, format=FORMAT, version=VERSION)
    gravity = physics.get("gravity")
    if not (
        isinstance(gravity, list)
        and len(gravity) == 3
        and all(isinstance(g, (int, float)) and math.isfinite(g) for g in gravity)
    ):
        raise InputError("expected a list of 3 finite numbers", source=str(path), field="gravity")
    tiny = 1e-12
    return PhysicsSettings(
        mass=check_number(physics, path, "mass", tiny),
        stiffness=check_number(physics, path, "stiffness", 0.0),
        damping=check_number(physics, path, "damping", 0.0),
        friction=check_number(physics, path, "friction", 0.0),
        spring_exponent=check_number(physics, path, "spring_exponent", 0.0, 10.0),
        restitution=check_number(physics, path, "restitution", 0.0, 1.0),
        frame_dt=check_number(physics, path, "frame_dt", tiny),
        substeps=check_number(physics, path, "substeps", 1, 1_000_000, integer=True),
        gravity=tuple(float(g) for g in gravity),
        ground_height=check_number(physics, path, "ground_height"),
        num_anchors=check_number(physics, path, "num_anchors", 2, integer=True),
        num_neighbors=check_number(physics, path, "num_neighbors", 1, integer=True),
        binding_neighbors=check_number(physics, path, "binding_neighbors", 1, integer=True),
        binding_power=check_number(physics, path, "binding_power", 0.0),
        object_id=str(physics.get("object_id", "")),
    )


def read_asset(folder: str | os.PathLike) -> Asset:
    """Read and validate an asset folder."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError("asset folder not found", source=str(folder))
    physics = _read_physics(folder / "physics.json")
    gaussians = read_ply(folder / "gaussians.ply")

    path = folder / "anchors.npz"
    data = read_npz(path)
    x0 = check_array(data, path, "x0", "f", (None, 3))
    n_a = x0.shape[0]
    v0 = check_array(data, path, "v0", "f", (n_a, 3))
    springs = check_array(data, path, "springs", "i", (None, 2))
    rest_length = check_array(data, path, "rest_length", "f", (springs.shape[0],))
    per_element = {}
    for name in PER_ANCHOR_ARRAYS + PER_SPRING_ARRAYS:
        if name in data:
            size = n_a if name in PER_ANCHOR_ARRAYS else springs.shape[0]
            per_element[name] = torch.from_numpy(check_array(data, path, name, "f", (size,)).copy())

    path = folder / "binding.npz"
    data = read_npz(path)
    index = check_array(data, path, "index", "i", (gaussians.num_gaussians, None))
    weight = check_array(data, path, "weight", "f", index.shape)

    asset = Asset(
        gaussians=gaussians,
        x0=torch.from_numpy(x0.astype(np.float32)),
        v0=torch.from_numpy(v0.astype(np.float32)),
        springs=torch.from_numpy(springs.astype(np.int64)),
        rest_length=torch.from_numpy(rest_length.astype(np.float32)),
        binding_index=torch.from_numpy(index.astype(np.int64)),
        binding_weight=torch.from_numpy(weight.astype(np.float32)),
        physics=physics,
        per_element=per_element,
    )
    validate_asset(asset, str(folder))
    return asset


def validate_asset(asset: Asset, where: str) -> None:
    """Check the cross-file invariants; raises InputError naming file and field."""
    anchors = os.path.join(where, "anchors.npz")
    binding = os.path.join(where, "binding.npz")
    physics = os.path.join(where, "physics.json")
    n_a = asset.num_anchors
    springs = asset.springs
    if springs.numel() and (springs.min() < 0 or springs.max() >= n_a):
        bad = int(springs.max()) if springs.max() >= n_a else int(springs.min())
        raise InputError(f"index {bad} outside [0, {n_a})", source=anchors, field="springs")
    if (springs[:, 0] == springs[:, 1]).any():
        raise InputError("a spring joins an anchor to itself", source=anchors, field="springs")
    if not (torch.isfinite(asset.rest_length).all() and (asset.rest_length > 0).all()):
        raise InputError("must be finite and > 0", source=anchors, field="rest_length")
    for name, t in (("x0", asset.x0), ("v0", asset.v0)):
        if not torch.isfinite(t).all():
            raise InputError("contains NaN or inf", source=anchors, field=name)
    for name, t in asset.per_element.items():
        positive = name == "mass"
        if not torch.isfinite(t).all() or (t <= 0 if positive else t < 0).any():
            raise InputError("must be finite and " + ("> 0" if positive else ">= 0"), anchors, name)
    p = asset.physics
    if not p.mass > 0:
        raise InputError(f"{p.mass} must be > 0", source=physics, field="mass")
    for name in ("stiffness", "damping", "friction"):
        if not getattr(p, name) >= 0:
            raise InputError(f"{getattr(p, name)} must be >= 0", source=physics, field=name)
    if p.num_anchors != n_a:
        raise InputError(
            f"{p.num_anchors} does not match the {n_a} anchors of anchors.npz",
            source=physics,
            field="num_anchors",
        )
    index, weight = asset.binding_index, asset.binding_weight
    if index.shape[0] != asset.gaussians.num_gaussians:
        raise InputError(
            f"{index.shape[0]} rows for {asset.gaussians.num_gaussians} Gaussians",
            source=binding,
            field="index",
        )
    if index.numel() and (index.min() < 0 or index.max() >= n_a):
        raise InputError(f"indices outside [0, {n_a})", source=binding, field="index")
    if not torch.isfinite(weight).all() or (weight < 0).any():
        raise InputError("must be finite and >= 0", source=binding, field="weight")
    if weight.numel() and not torch.allclose(weight.double().sum(1), torch.ones(1).double(), 1e-4):
        raise InputError("rows must sum to 1", source=binding, field="weight")
