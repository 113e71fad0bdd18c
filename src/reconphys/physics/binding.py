"""Binding of Gaussian centres to anchors by inverse-distance weights
(docs/design.md#physical-model).

Each Gaussian follows its ``n_b`` nearest anchors (at rest): ``μ_t = μ_0 + Σ_b w_b (x_t − x_0)[b]``
with ``w ∝ 1 / r^p_b``. Rotation, scale, colour and opacity stay fixed.
"""

from __future__ import annotations

import numpy as np
import torch
from scipy.spatial import cKDTree
from torch import Tensor


def compute_binding(
    gaussian_means: Tensor,  # [N, 3] rest centres, metres
    anchors: Tensor,  # [N_A, 3] rest anchor positions, metres
    num_neighbors: int = 16,  # n_b
    power: float = 2.0,  # p_b
    min_distance: float = 1e-6,  # metres; distances are clamped here so a coincident pair is finite
) -> tuple[Tensor, Tensor]:
    """Returns ``index [N, n_b]`` int64 and ``weight [N, n_b]`` float32 (rows sum to 1)."""
    anchor_np = torch.as_tensor(anchors).detach().cpu().double().numpy()
    means_np = torch.as_tensor(gaussian_means).detach().cpu().double().numpy()
    k = min(num_neighbors, anchor_np.shape[0])
    distance, index = cKDTree(anchor_np).query(means_np, k=k)
    distance = np.maximum(distance.reshape(len(means_np), k), min_distance)
    index = index.reshape(len(means_np), k)
    weight = distance ** (-power)
    weight /= weight.sum(1, keepdims=True)
    return torch.from_numpy(index.astype(np.int64)), torch.from_numpy(weight.astype(np.float32))


def deform_means(
    rest_means: Tensor,  # [..., N, 3] Gaussian centres at rest
    rest_anchors: Tensor,  # [..., N_A, 3] anchor positions at rest (x_0)
    anchors: Tensor,  # [..., N_A, 3] anchor positions now (x_t)
    index: Tensor,  # [N, n_b] int64
    weight: Tensor,  # [N, n_b]
) -> Tensor:  # [..., N, 3]
    """Move Gaussian centres with the weighted displacement of their bound anchors.

    Leading dims of ``anchors`` (e.g. ``[B, T]``) broadcast against ``rest_anchors``/``rest_means``.
    """
    displacement = anchors - rest_anchors  # [..., N_A, 3]
    bound = displacement[..., index, :]  # [..., N, n_b, 3]
    return rest_means + (weight.to(bound.dtype)[..., None] * bound).sum(-2)
