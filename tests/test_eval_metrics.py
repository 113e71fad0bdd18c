"""Metrics against independent implementations: scikit-image, brute force, exact cases."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest
import torch
from skimage.metrics import peak_signal_noise_ratio, structural_similarity

from reconphys.eval.metrics import (
    attribute_errors,
    chamfer_distance,
    earth_movers_distance,
    foreground_mask,
    psnr,
    ssim,
    ssim_map,
)


def images(seed=0, size=24):
    g = torch.Generator().manual_seed(seed)
    target = torch.rand(size, size, 3, generator=g, dtype=torch.float64)
    target[: size // 3] = 0.0  # a black background band
    prediction = target + 0.05 * torch.randn(target.shape, generator=g, dtype=torch.float64)
    return prediction.clamp(0, 1), target


def test_psnr_matches_skimage_on_the_whole_image_and_on_the_foreground():
    prediction, target = images()
    everything = torch.ones(target.shape[:2], dtype=torch.bool)
    expected = peak_signal_noise_ratio(target.numpy(), prediction.numpy(), data_range=1.0)
    assert psnr(prediction, target, everything).item() == pytest.approx(expected, rel=1e-10)
    mask = foreground_mask(target)
    assert 0 < mask.sum() < mask.numel()
    rows = mask.numpy()
    expected_fg = peak_signal_noise_ratio(
        target.numpy()[rows], prediction.numpy()[rows], data_range=1.0
    )
    assert psnr(prediction, target).item() == pytest.approx(expected_fg, rel=1e-10)


def test_psnr_batches_and_empty_mask():
    prediction, target = images()
    batch = psnr(torch.stack([prediction, target]), torch.stack([target, target]))
    assert batch.shape == (2,) and batch[1] > 150  # identical images: only the clamp floor
    assert math.isnan(psnr(prediction, torch.zeros_like(target)).item())


@pytest.mark.parametrize("size", [12, 24])
def test_ssim_map_matches_skimage(size):
    prediction, target = images(size=size)
    _, full = structural_similarity(
        target.numpy(),
        prediction.numpy(),
        gaussian_weights=True,
        sigma=1.5,
        use_sample_covariance=False,
        data_range=1.0,
        channel_axis=-1,
        full=True,
    )
    ours = ssim_map(prediction, target).numpy()
    np.testing.assert_allclose(ours, full.mean(-1), atol=1e-10)
    mask = foreground_mask(target)
    expected = full.mean(-1)[mask.numpy()].mean()
    assert ssim(prediction, target).item() == pytest.approx(expected, rel=1e-10)


def brute_force_chamfer(p, t):
    d = ((p[:, None, :] - t[None, :, :]) ** 2).sum(-1)
    return d.min(1).mean() + d.min(0).mean()


def test_chamfer_matches_brute_force_and_is_symmetric():
    rng = np.random.default_rng(0)
    p, t = rng.normal(size=(300, 3)), rng.normal(size=(200, 3)) + 0.1
    ours = chamfer_distance(torch.from_numpy(p), torch.from_numpy(t))
    assert ours == pytest.approx(brute_force_chamfer(p, t), rel=1e-12)
    assert chamfer_distance(torch.from_numpy(t), torch.from_numpy(p)) == pytest.approx(ours)
    assert chamfer_distance(torch.from_numpy(p), torch.from_numpy(p)) == pytest.approx(0, abs=1e-12)


def test_emd_matches_permutation_brute_force():
    rng = np.random.default_rng(1)
    p, t = rng.normal(size=(6, 3)), rng.normal(size=(6, 3))
    cost = np.linalg.norm(p[:, None] - t[None], axis=-1)
    best = min(cost[range(6), perm].mean() for perm in itertools.permutations(range(6)))
    assert earth_movers_distance(torch.from_numpy(p), torch.from_numpy(t)) == pytest.approx(best)


def test_emd_of_a_translated_set_is_the_translation():
    """A shifted copy (shift smaller than half the spacing) matches point to point."""
    axes = [torch.arange(6, dtype=torch.float64)] * 3
    grid = torch.stack(torch.meshgrid(*axes, indexing="ij"), -1).reshape(-1, 3)
    shift = torch.tensor([0.1, -0.2, 0.05], dtype=torch.float64)
    emd = earth_movers_distance(grid, grid + shift, num_points=10_000)
    assert emd == pytest.approx(shift.norm().item(), rel=1e-9)


def test_attribute_errors_include_observables():
    true = {n: torch.tensor([1.0, 2.0]) for n in ("mass", "stiffness", "damping", "friction")}
    predicted = {n: 2 * v for n, v in true.items()}  # m, k, d all doubled: ratios unchanged
    errors = attribute_errors(predicted, true)
    assert errors["mass"] == pytest.approx(1.5) and errors["friction"] == pytest.approx(1.5)
    assert errors["log_k_over_m"] == pytest.approx(0.0, abs=1e-7)
    assert errors["log_d_over_m"] == pytest.approx(0.0, abs=1e-7)


def write_fake_lpips_weights(folder, seed=0):
    """Files with the published key names and shapes, random values (the real ones are not
    downloadable here)."""
    from reconphys.eval.lpips import ALEXNET_FILE, HEADS_FILE, AlexLPIPS

    torch.manual_seed(seed)
    reference = AlexLPIPS()
    alexnet = {f"features.{k}": v.clone() for k, v in reference.features.state_dict().items()}
    alexnet["classifier.1.weight"] = torch.zeros(2, 2)  # other keys of the real file are ignored
    for head in reference.heads:  # LPIPS heads are non-negative
        head.weight.data.abs_()
    heads = {f"lin{i}.model.1.weight": h.weight.clone() for i, h in enumerate(reference.heads)}
    torch.save(alexnet, folder / ALEXNET_FILE)
    torch.save(heads, folder / HEADS_FILE)
    return reference


def test_lpips_is_unavailable_without_weights(monkeypatch, tmp_path):
    from reconphys.eval import lpips

    monkeypatch.setenv("RECONPHYS_LPIPS_DIR", str(tmp_path))
    monkeypatch.setattr(lpips, "_candidates", lambda: [tmp_path])
    assert lpips.load_lpips() is None


def test_lpips_loads_local_weights_and_behaves_like_a_distance(monkeypatch, tmp_path):
    from reconphys.eval import lpips

    reference = write_fake_lpips_weights(tmp_path)
    monkeypatch.setattr(lpips, "_candidates", lambda: [tmp_path])
    model = lpips.load_lpips()
    assert model is not None
    for a, b in zip(model.state_dict().values(), reference.state_dict().values(), strict=True):
        assert torch.equal(a, b)
    prediction, target = images(size=32)
    p, t = prediction.float(), target.float()
    same = model(t, t)
    near = model(p, t)
    far = model(torch.rand_like(t), t)
    assert same.item() == pytest.approx(0.0, abs=1e-7)
    assert 0 < near.item() < far.item()
    assert model(t, p).item() == pytest.approx(near.item(), rel=1e-5)
    assert model(torch.stack([p, t]), torch.stack([t, t])).shape == (2,)
