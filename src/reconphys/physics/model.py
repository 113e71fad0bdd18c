"""Spring-mass model: topology (springs, rest lengths) and physical attributes
(docs/design.md#physical-model).

The model is fixed during a rollout; positions and velocities live in :class:`State`. Attributes may
be one value per scene or one value per anchor (mass, friction) / per spring (stiffness, damping).
Every tensor is normalised on construction to a broadcastable batched shape:

- ``mass``, ``friction``: ``[B or 1, N_A or 1]``
- ``stiffness``, ``damping``: ``[B or 1, E or 1]``

A 0-d value means "one value for every scene", a 1-d value of length B "one value per scene", and a
2-d value ``[B, N_A]`` / ``[B, E]`` per anchor / per spring.

Units: mass in kg per anchor; stiffness k in N per unit strain (spring constant k / l in N/m);
damping d in N·s per unit strain rate (the dashpot constant is d / l in N·s/m); friction f is the
Coulomb coefficient (dimensionless); gravity in m/s²; lengths in metres.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields, replace

import numpy as np
import torch
from scipy.spatial import cKDTree
from torch import Tensor

GRAVITY = (0.0, 0.0, -9.8)  # m/s², world z up
ATTRIBUTES = ("mass", "stiffness", "damping", "friction")  # the four the network predicts

# Attribute ranges of the synthetic data (docs/design.md#attribute-ranges); the stability bound
# covers all of them.
ATTRIBUTE_RANGES = {
    "mass": (0.2, 6.0),
    "stiffness": (10.0, 1200.0),
    "damping": (0.1, 5.0),
    "friction": (0.0, 1.0),
}


def observable_bounds() -> Tensor:
    """[3, 2] the reachable (lo, hi) of the observables a video determines — log k/m, log d/m
    (natural logs of the SI ratios) and friction — inside :data:`ATTRIBUTE_RANGES`: k/m from
    k_lo/m_hi to k_hi/m_lo, and so on (float64)."""
    r = ATTRIBUTE_RANGES
    (m_lo, m_hi), (k_lo, k_hi), (d_lo, d_hi) = r["mass"], r["stiffness"], r["damping"]
    return torch.tensor(
        [
            [math.log(k_lo / m_hi), math.log(k_hi / m_lo)],
            [math.log(d_lo / m_hi), math.log(d_hi / m_lo)],
            list(r["friction"]),
        ],
        dtype=torch.float64,
    )


def _batched(value, dtype: torch.dtype, device) -> Tensor:
    """Scalar → [1, 1], per-scene [B] → [B, 1], per-element [B, M] as is."""
    t = torch.as_tensor(value, dtype=dtype, device=device)
    if t.dim() == 0:
        return t.reshape(1, 1)
    if t.dim() == 1:
        return t[:, None]
    if t.dim() == 2:
        return t
    raise ValueError(f"attribute must be 0-, 1- or 2-dimensional, got shape {tuple(t.shape)}")


@dataclass
class SpringMassModel:
    """Topology and attributes of a batch of spring-mass systems with the same anchor count.

    Springs are undirected pairs; each acts equally and oppositely on both ends. One topology can
    be shared by the whole batch (``springs [E, 2]``) or given per scene (``[B, E, 2]``; pad with
    zero-stiffness, zero-damping springs of any positive rest length to equalise E).
    """

    springs: Tensor  # [E, 2] or [B, E, 2] int64 anchor indices
    rest_length: Tensor  # [E] or [B, E] metres, > 0
    mass: Tensor  # kg per anchor; [B|1, N_A|1] after construction
    stiffness: Tensor  # N per unit strain; [B|1, E|1]
    damping: Tensor  # N·s per unit strain rate; [B|1, E|1]
    friction: Tensor  # Coulomb coefficient; [B|1, N_A|1]
    spring_exponent: float = 0.5  # p_k: F = k ε (1 + |ε|)^p_k; 0 is Hooke's law
    restitution: float = 0.0  # e: normal velocity after contact is −e v_n
    gravity: tuple[float, float, float] = GRAVITY  # m/s²
    ground_height: float = 0.0  # metres; the ground is the plane z = ground_height
    dtype: torch.dtype = field(default=torch.float32, repr=False)
    gravity_vector: Tensor = field(init=False, repr=False)  # [3] m/s², derived from gravity

    def __post_init__(self):
        device = self.springs.device
        self.springs = self.springs.to(device=device, dtype=torch.int64)
        self.rest_length = self.rest_length.to(device=device, dtype=self.dtype)
        for name in ATTRIBUTES:
            setattr(self, name, _batched(getattr(self, name), self.dtype, device))
        self.gravity = tuple(float(g) for g in self.gravity)
        # Kept on the device so that a substep does no host-to-device copy.
        self.gravity_vector = torch.tensor(self.gravity, dtype=self.dtype, device=device)

    @property
    def device(self) -> torch.device:
        return self.springs.device

    @property
    def num_springs(self) -> int:
        return self.springs.shape[-2]

    @property
    def batch_size(self) -> int:
        """Largest batch size implied by the model's tensors (1 when everything is shared)."""
        sizes = [self.mass.shape[0], self.stiffness.shape[0], self.damping.shape[0]]
        sizes += [self.friction.shape[0]]
        if self.springs.dim() == 3:
            sizes.append(self.springs.shape[0])
        return max(sizes)

    def to(self, device=None, dtype: torch.dtype | None = None) -> SpringMassModel:
        dtype = dtype or self.dtype
        tensors = {
            f.name: getattr(self, f.name).to(device=device)
            for f in fields(self)
            if f.init and isinstance(getattr(self, f.name), Tensor)
        }
        return replace(self, **tensors, dtype=dtype)

    def with_attributes(self, **attributes) -> SpringMassModel:
        """Same topology with new attribute values (mass, stiffness, damping, friction, ...)."""
        return replace(self, **attributes)


def knn_springs(
    anchors: Tensor | np.ndarray,  # [N_A, 3] rest positions, metres
    num_neighbors: int = 32,
) -> tuple[Tensor, Tensor]:
    """Undirected springs from the union of each anchor's K nearest neighbours.

    Returns ``springs [E, 2]`` int64 with ``i < j``, sorted lexicographically, each pair once, and
    ``rest_length [E]`` (float32, metres) from the given positions.
    """
    points = torch.as_tensor(anchors).detach().cpu().double().numpy()
    n = points.shape[0]
    k = min(num_neighbors, n - 1)
    if k < 1:
        raise ValueError(f"need at least 2 anchors to make springs, got {n}")
    _, neighbors = cKDTree(points).query(points, k=k + 1)
    i = np.repeat(np.arange(n), k)
    j = neighbors[:, 1:].reshape(-1)
    pairs = np.unique(np.sort(np.stack([i, j], axis=1), axis=1), axis=0)
    pairs = pairs[pairs[:, 0] != pairs[:, 1]]  # duplicate points could list themselves
    rest = np.linalg.norm(points[pairs[:, 1]] - points[pairs[:, 0]], axis=1)
    return torch.from_numpy(pairs.astype(np.int64)), torch.from_numpy(rest.astype(np.float32))
