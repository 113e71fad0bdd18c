"""The clip's own colour model on the segmenter's logits (models/mask_colours.py)."""

import numpy as np
import torch
from scipy import ndimage, optimize

from reconphys.models.mask_colours import (
    BAND_PX,
    CONFIDENT_LOGIT,
    colour_refined,
    fit_logistic,
    near_object,
)
from reconphys.models.mask_segmenter import clip_references, keep_main_blob


def test_fit_logistic_is_the_penalised_log_loss_minimum():
    """Newton's answer against scipy's BFGS on the same objective."""
    rng = np.random.default_rng(0)
    x = rng.normal(size=(400, 5))
    y = (x @ [1.5, -2.0, 0.5, 0.0, 1.0] + 0.3 + rng.normal(size=400) > 0).astype(float)
    ridge = 1e-2

    def objective(w):
        z = x @ w[:-1] + w[-1]
        return np.mean(np.logaddexp(0, z) - y * z) + ridge * np.sum(w[:-1] ** 2)

    reference = optimize.minimize(objective, np.zeros(6), method="BFGS", options={"gtol": 1e-10})
    ours = fit_logistic(torch.from_numpy(x).float(), torch.from_numpy(y).float(), ridge)
    np.testing.assert_allclose(ours.numpy(), reference.x, atol=1e-4)


def test_near_object_is_a_square_dilation():
    rng = np.random.default_rng(1)
    masks = rng.random((4, 40, 56)) > 0.995
    masks[2] = False  # an empty frame
    masks[1, 0, 55] = True  # at a corner
    expected = ndimage.binary_dilation(masks, structure=np.ones((1, 2 * 3 + 1, 2 * 3 + 1)))
    assert np.array_equal(near_object(torch.from_numpy(masks), band=3).numpy(), expected)
    assert not near_object(torch.zeros(2, 8, 8, dtype=torch.bool)).any()


def _clip(frames: int = 6, size: int = 48, seed: int = 0):
    """A red square falling over a noisy grey-green floor with a dark shadow beside it:
    frames [T, H, W, 3], the true masks [T, H, W] and the shadow's [T, H, W]."""
    g = torch.Generator().manual_seed(seed)
    floor = torch.tensor([0.45, 0.5, 0.4]) + 0.05 * torch.randn(size, size, 3, generator=g)
    video = floor.expand(frames, -1, -1, -1).clone()
    truth = torch.zeros(frames, size, size, dtype=torch.bool)
    shadow = torch.zeros_like(truth)
    for t in range(frames):
        top = 8 + 3 * t
        truth[t, top : top + 12, 16:28] = True
        shadow[t, top + 12 : top + 15, 18:30] = True
    video[shadow] *= 0.5
    video[truth] = torch.tensor([0.8, 0.2, 0.15]) + 0.03 * torch.randn(
        int(truth.sum()), 3, generator=g
    )
    return video.clamp(0, 1), truth, shadow


def test_colour_refined_takes_in_the_missed_half_and_drops_the_shadow():
    frames, truth, shadow = _clip()
    left = truth.clone()
    left[..., 22:] = False
    logits = torch.full(truth.shape, -8.0)
    logits[left] = 8.0
    logits[truth & ~left] = -1.0  # the network unsure of the object's right half: missed
    logits[shadow] = 0.5  # and unsure of the shadow: taken in
    base = keep_main_blob(logits > 0)
    refined = colour_refined(logits, frames, clip_references(frames), base)

    def iou(m):
        return float((m & truth).sum() / (m | truth).sum())

    assert iou(base) < 0.6
    assert iou(refined > 0) > 0.97
    assert (refined > 0)[shadow].float().mean() < 0.05  # all of it in before
    sure = logits.abs() > CONFIDENT_LOGIT
    assert ((refined > 0) == (logits > 0))[sure].all()  # the sure pixels keep their side


def test_colour_refined_leaves_far_pixels_and_unsure_clips_alone():
    frames, truth, _ = _clip()
    logits = torch.where(truth, 8.0, -8.0)
    logits[:, :4, -4:] = 0.5  # a speck far from the object, unsure (not in the main blob)
    base = keep_main_blob(logits > 0)
    refined = colour_refined(logits, frames, clip_references(frames), base)
    far = ~near_object(base)
    assert far.any() and torch.equal(refined[far], logits[far])
    assert (refined[:, :4, -4:] > 0).all()  # too far to be judged
    unsure = torch.where(truth, 2.0, -2.0)  # no pixel the network is sure of
    assert colour_refined(unsure, frames, clip_references(frames), truth) is unsure


def test_the_default_band_reaches_the_missed_half():
    _, truth, _ = _clip()
    assert near_object(truth & (torch.arange(48) < 22), BAND_PX)[truth].all()
