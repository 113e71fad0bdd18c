"""The clip's own colours: a per-clip second look at the mask segmenter's logits
(docs/usage.md#the-clips-own-colours).

The segmenter learnt what objects, floors and shadows look like in its training renders. In a
recording unlike them (another renderer, another camera) it is unsure of parts of the object —
a lit face near the floor's colours — that the same clip shows plainly elsewhere. Within one
clip, the pixels it is sure of teach the difference: a ridge-penalised logistic regression on
per-pixel colour features (:func:`colour_features`: the frame, its differences from the clip's
reference frames, chromaticity, squares and products) is fitted to the confident pixels within
:data:`BAND_PX` of the object (logit above :data:`CONFIDENT_LOGIT` and in the main blob: object;
below minus it: background), and its logit, clamped to ±:data:`MAX_SHIFT` and weighed by
:data:`WEIGHT`, is added to the network's on that band. Pixels far from the object are left as
they were, so the refinement can move the outline, not add an object elsewhere. A clip with too
few sure pixels of either kind is returned unchanged. 20–45 ms a 128-px clip on a 2-core CPU
(docs/benchmarks.md); it runs on the CPU whatever the logits' device.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from ..capture.window import pixel_bounds

CONFIDENT_LOGIT = 4.0  # |logit| above this: a pixel the network is sure of (ensemble mean)
BAND_PX = 8  # the refinement acts within this many pixels of the object's main blob
MAX_SHIFT = 6.0  # the colour model's logit is clamped to ±this, then weighed by WEIGHT
WEIGHT = 0.7  # chosen on validation sets (docs/usage.md#the-clips-own-colours) among 0.5, 0.7, 1
MAX_SAMPLES = 8000  # sure pixels fitted on, half object, half background (a seeded draw)
MIN_SAMPLES = 20  # of each kind; fewer: the clip is left as it was
RIDGE = 1e-3  # the L2 penalty per sample on the standardised features' weights (not the bias)
NEWTON_STEPS = 12


def colour_features(
    pixels: Tensor,  # [N, 3] in [0, 1]: a frame's pixels
    references: Tensor,  # [3, N, 3]: A, Z and M (clip_references) at the same pixels
) -> Tensor:  # [N, 26]
    """Per-pixel features: the colour, its differences from the three references and their
    lengths, chromaticity (r, g), squares of the colour and of its difference from the median
    frame, and the colour's three products."""
    differences = [pixels - reference for reference in references]
    chroma = pixels / pixels.sum(-1, keepdim=True).clamp_min(1e-3)
    r, g, b = pixels.unbind(-1)
    return torch.cat(
        [
            pixels,
            *differences,
            chroma[:, :2],
            torch.stack([d.norm(dim=-1) for d in differences], -1),
            pixels**2,
            differences[2] ** 2,
            torch.stack([r * g, g * b, r * b], -1),
        ],
        -1,
    )


def fit_logistic(
    features: Tensor,  # [N, C] (standardised)
    labels: Tensor,  # [N] in {0, 1}
    ridge: float = RIDGE,
    steps: int = NEWTON_STEPS,
) -> Tensor:  # [C + 1] weights, the bias last
    """Minimiser of the mean log-loss + ``ridge`` · |w|² (bias unpenalised) by Newton's method
    in float64."""
    x = torch.cat([features, torch.ones(len(features), 1)], 1).double()
    y = labels.double()
    count, size = x.shape
    penalty = torch.full((size,), 2.0 * ridge, dtype=torch.float64)
    penalty[-1] = 1e-9  # the bias: unpenalised (a little for a flat clip's singular Hessian)
    weights = torch.zeros(size, dtype=torch.float64)
    for _ in range(steps):
        p = torch.sigmoid(x @ weights)
        gradient = x.T @ (p - y) / count + penalty * weights
        hessian = (x * (p * (1 - p))[:, None]).T @ x / count + torch.diag(penalty)
        step = torch.linalg.solve(hessian, gradient)
        weights -= step
        if float(step.abs().max()) < 1e-6:
            break
    return weights.float()


def near_object(masks: Tensor, band: int = BAND_PX) -> Tensor:
    """Pixels [T, H, W] bool within ``band`` px (a square's reach) of ``masks`` [T, H, W] bool:
    window sums by cumulative sums along each axis (a separable max filter), over the masks'
    bounding box only (a few ms a 128-px clip, where a stride-1 max_pool2d over the whole frames
    took tens)."""

    def spread(x: Tensor, dim: int) -> Tensor:
        size = x.shape[dim]
        sums = F.pad(x.cumsum(dim).movedim(dim, -1), (1, 0)).movedim(-1, dim)
        index = torch.arange(size, device=x.device)
        upper = (index + band + 1).clamp_max(size)
        lower = (index - band).clamp_min(0)
        return sums.index_select(dim, upper) - sums.index_select(dim, lower)

    near = torch.zeros_like(masks, dtype=torch.bool)
    bounds = pixel_bounds(masks.any(0))
    if bounds is None:
        return near
    top, bottom, left, right = bounds
    top, left, bottom, right = max(top - band, 0), max(left - band, 0), bottom + band, right + band
    crop = masks[:, top:bottom, left:right].to(torch.int32)
    near[:, top:bottom, left:right] = spread(spread(crop, 2), 1) > 0
    return near


def colour_refined(
    logits: Tensor,  # [T, H, W] the segmenter's
    frames: Tensor,  # [T, H, W, 3] in [0, 1]
    references: Tensor,  # [3, 3, H, W] clip_references(frames)
    main_blob: Tensor,  # [T, H, W] bool: keep_main_blob(logits > 0)
) -> Tensor:  # [T, H, W]
    """The logits with the clip's colour model's logit (clamped, weighed) added within BAND_PX of
    the main blob; the logits unchanged when fewer than MIN_SAMPLES sure pixels of either kind."""
    device = logits.device
    logits, frames, references, main_blob = (
        x.cpu() for x in (logits, frames, references, main_blob)
    )
    band = near_object(main_blob)
    where = band.nonzero(as_tuple=True)
    at = references.permute(0, 2, 3, 1)[:, where[1], where[2]]  # [3, N, 3]
    features = colour_features(frames[where], at)
    values = logits[where]
    sure_object = (values > CONFIDENT_LOGIT) & main_blob[where]
    sure_background = values < -CONFIDENT_LOGIT
    if min(int(sure_object.sum()), int(sure_background.sum())) < MIN_SAMPLES:
        return logits.to(device)
    generator = torch.Generator().manual_seed(0)
    picked = [
        indices[torch.randperm(len(indices), generator=generator)[: MAX_SAMPLES // 2]]
        for indices in (sure_object.nonzero()[:, 0], sure_background.nonzero()[:, 0])
    ]
    samples = features[torch.cat(picked)]
    labels = torch.cat([torch.ones(len(picked[0])), torch.zeros(len(picked[1]))])
    mean, spread = samples.mean(0), samples.std(0).clamp_min(1e-3)
    weights = fit_logistic((samples - mean) / spread, labels)
    shift = ((features - mean) / spread) @ weights[:-1] + weights[-1]
    refined = logits.clone()
    refined[where] = values + WEIGHT * shift.clamp(-MAX_SHIFT, MAX_SHIFT)
    return refined.to(device)
