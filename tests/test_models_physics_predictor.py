"""Physics predictor: shapes, bounds, invertible attribute normalisation, gradients."""

from __future__ import annotations

import pytest
import torch

from reconphys.models.encoders import ENCODERS, SmallCNN
from reconphys.models.physics_predictor import (
    PhysicsPredictor,
    PredictorConfig,
    attributes_from_unit,
    motion_channels,
    normalize_attributes,
    silhouette_statistics,
)
from reconphys.physics.model import ATTRIBUTE_RANGES, ATTRIBUTES

TINY = PredictorConfig(
    encoder_channels=(8, 16), token_channels=16, trunk_blocks=1, attention_heads=2,
    mlp_hidden=(32,), num_frames=6, resolution=32,
)  # fmt: skip


def test_outputs_lie_in_the_attribute_ranges():
    torch.manual_seed(0)
    model = PhysicsPredictor(TINY)
    frames = torch.rand(3, 6, 32, 32, 3)
    out = model(frames)
    assert out["unit"].shape == (3, 4)
    for name in ATTRIBUTES:
        low, high = ATTRIBUTE_RANGES[name]
        assert out[name].shape == (3,)
        assert (out[name] >= low).all() and (out[name] <= high).all(), name


def test_extreme_logits_reach_the_range_ends():
    ends = attributes_from_unit(torch.tensor([[0.0] * 4, [1.0] * 4], dtype=torch.float64))
    for name in ATTRIBUTES:
        low, high = ATTRIBUTE_RANGES[name]
        assert ends[name].tolist() == pytest.approx([low, high], rel=1e-12), name


def test_normalisation_inverts_the_bounded_map():
    unit = torch.rand(50, 4, dtype=torch.float64)
    back = normalize_attributes(attributes_from_unit(unit))
    torch.testing.assert_close(back, unit, rtol=0, atol=1e-12)
    # the log-uniform midpoint of mass is the geometric mean of the range
    mid = attributes_from_unit(torch.full((1, 4), 0.5, dtype=torch.float64))
    assert mid["mass"].item() == pytest.approx((0.2 * 6.0) ** 0.5)


def test_gradient_reaches_every_parameter():
    torch.manual_seed(1)
    model = PhysicsPredictor(TINY)
    out = model(torch.rand(2, 6, 32, 32, 3))
    (out["stiffness"].log().sum() + out["friction"].sum()).backward()
    missing = [n for n, p in model.named_parameters() if p.grad is None or not p.grad.abs().sum()]
    assert not missing, missing


def test_fewer_frames_and_batch_independence():
    torch.manual_seed(2)
    model = PhysicsPredictor(TINY).eval()
    frames = torch.rand(2, 4, 32, 32, 3)
    both = model(frames)["unit"]
    one = model(frames[1:])["unit"]
    torch.testing.assert_close(both[1:], one, rtol=1e-5, atol=1e-6)


def test_bad_input_and_unknown_encoder():
    model = PhysicsPredictor(TINY)
    with pytest.raises(ValueError, match="frames"):
        model(torch.rand(2, 32, 32, 3))
    with pytest.raises(ValueError, match="at most 6"):
        model(torch.rand(1, 7, 32, 32, 3))
    with pytest.raises(ValueError, match="encoder"):
        PhysicsPredictor(PredictorConfig(encoder="nope"))
    assert "small_cnn" in ENCODERS


def test_config_round_trip():
    assert PredictorConfig.from_dict(TINY.to_dict()) == TINY


def test_coordinate_channels_make_pooled_features_see_position():
    """Without coords the stride-4 CNN is translation-equivariant (a blob moved by 4 px away from
    the borders gives the same spatially averaged features); with coords the average moves."""

    image = torch.zeros(2, 3, 64, 64)  # receptive field ±9 px: the blobs never see a border
    image[0, :, 28:34, 24:30] = 1.0
    image[1, :, 28:34, 32:38] = 1.0  # the same blob 8 px to the right
    torch.manual_seed(0)
    plain, coords = SmallCNN((4, 8)), SmallCNN((4, 8), coords=True)
    with torch.no_grad():
        p, c = plain(image).mean((-2, -1)), coords(image).mean((-2, -1))
    torch.testing.assert_close(p[0], p[1], rtol=0, atol=1e-5)
    assert (c[0] - c[1]).abs().max() > 1e-3
    with pytest.raises(ValueError, match="coords"):
        PhysicsPredictor(PredictorConfig(extra={"colour": True}))


def test_silhouette_statistics_match_numpy_moments():
    """A lit rectangle on black: area, centroid and central moments of its pixel coordinates
    (numpy, in [−1, 1]); moving it 3 px moves only the centroid, by 3 pixel pitches."""
    import numpy as np

    h, w = 24, 32
    frames = torch.zeros(1, 3, h, w, 3, dtype=torch.float64)
    frames[0, 0, 5:12, 4:15] = torch.tensor([0.8, 0.3, 0.1], dtype=torch.float64)
    frames[0, 1, 5:12, 7:18] = 0.5  # the same rectangle 3 px to the right
    stats = silhouette_statistics(frames)[0]
    ys, xs = np.meshgrid(np.linspace(-1, 1, h)[5:12], np.linspace(-1, 1, w)[4:15], indexing="ij")
    expected = [
        xs.size / (h * w), xs.mean(), ys.mean(), xs.var(), ys.var(),
        ((xs - xs.mean()) * (ys - ys.mean())).mean(),
    ]  # fmt: skip
    np.testing.assert_allclose(stats[0].numpy(), expected, rtol=1e-12, atol=1e-15)
    moved = stats[1] - stats[0]
    np.testing.assert_allclose(moved.numpy(), [0, 3 * 2 / (w - 1), 0, 0, 0, 0], atol=1e-12)
    assert (stats[2] == 0).all()  # an empty frame


def test_silhouette_statistics_weigh_edge_pixels_by_coverage():
    """A dim edge column (half the object level) pulls the centroid half as much as a lit one."""
    frames = torch.zeros(1, 2, 8, 9, 3, dtype=torch.float64)
    frames[0, :, 2:6, 3:5] = 1.0
    frames[0, 0, 2:6, 5] = 0.025  # half of OBJECT_LEVEL: weight 0.5
    frames[0, 1, 2:6, 5] = 1.0
    cx = silhouette_statistics(frames)[0, :, 1]
    pitch = 2 / 8
    x = torch.linspace(-1, 1, 9, dtype=torch.float64)
    assert cx[0].item() == pytest.approx(((x[3] + x[4] + 0.5 * x[5]) / 2.5).item())
    assert cx[1].item() == pytest.approx((x[4]).item()) and x[5] - x[4] == pytest.approx(pitch)


def test_silhouette_branch_is_optional_and_trained():
    """model.silhouette adds the branch; its weights get a gradient; old configs load without."""
    torch.manual_seed(0)
    config = PredictorConfig(**{**TINY.to_dict(), "silhouette": True})
    model = PhysicsPredictor(config)
    frames = torch.zeros(2, 4, 32, 32, 3)  # fewer frames than num_frames (6)
    for t in range(4):  # one square slides, the other squashes
        frames[0, t, 10:20, 10 + t : 20 + t] = 0.7
        frames[1, t, 12 + t : 22, 8 - t : 18 + t] = 0.7
    out = model(frames)
    out["unit"].sum().backward()
    assert all(p.grad is not None and p.grad.abs().sum() > 0 for p in model.silhouette.parameters())
    assert not torch.allclose(out["unit"][0], out["unit"][1])
    legacy = {k: v for k, v in TINY.to_dict().items() if k != "silhouette"}
    assert PredictorConfig.from_dict(legacy).silhouette is False
    assert PhysicsPredictor(PredictorConfig.from_dict(legacy)).silhouette is None


def test_motion_channels_are_the_frame_differences():
    torch.manual_seed(3)
    frames = torch.rand(2, 5, 8, 8, 3)
    out = motion_channels(frames)
    assert out.shape == (2, 5, 8, 8, 9)
    torch.testing.assert_close(out[..., :3], frames)
    assert not out[:, 0, ..., 3:].any()  # frame 0 has not changed
    t = 3
    torch.testing.assert_close(out[:, t, ..., 3:6], 4 * (frames[:, t] - frames[:, t - 1]))
    torch.testing.assert_close(out[:, t, ..., 6:], 4 * (frames[:, t] - frames[:, 0]))


def test_motion_option_feeds_the_encoder_and_loads_old_configs():
    """model.motion: the first convolution reads 9 channels; its motion weights matter for a
    moving video and not for a still one; other encoders refuse the option."""
    torch.manual_seed(4)
    model = PhysicsPredictor(PredictorConfig(**{**TINY.to_dict(), "motion": True})).eval()
    first = model.encoder.layers[0]
    assert first.in_channels == 9
    moving = torch.zeros(1, 4, 32, 32, 3)
    for t in range(4):
        moving[0, t, 10:20, 10 + t : 20 + t] = 0.7
    still = moving[:, -1:].expand(1, 4, 32, 32, 3)
    with torch.no_grad():
        before = [model(v)["unit"] for v in (moving, still)]
        first.weight[:, 3:] = 0  # blind the encoder to the motion channels
        after = [model(v)["unit"] for v in (moving, still)]
    assert not torch.allclose(before[0], after[0])
    torch.testing.assert_close(before[1], after[1])
    legacy = {k: v for k, v in TINY.to_dict().items() if k != "motion"}
    assert PredictorConfig.from_dict(legacy).motion is False
    with pytest.raises(ValueError, match="motion"):
        PhysicsPredictor(PredictorConfig(**{**TINY.to_dict(), "motion": True, "encoder": "timm"}))


# --- the track network ------------------------------------------------------------------------

TRACK = PredictorConfig(inputs="track", track_channels=16, mlp_hidden=(32,), num_frames=8)


def _sliding_square(distances: torch.Tensor, frames: int = 8) -> torch.Tensor:
    """[B, T, 32, 32, 3]: a 6-px grey square that slides ``distance`` pixels to the right over
    the clip (sub-pixel positions by coverage at its left and right edges)."""
    b = distances.shape[0]
    x = torch.arange(32, dtype=torch.float32) + 0.5  # pixel centres
    out = torch.zeros(b, frames, 32, 32, 3)
    for t in range(frames):
        left = 10.0 + distances * t / (frames - 1)  # [B]
        right = (x[None] + 0.5).minimum(left[:, None] + 6)
        coverage = (right - (x[None] - 0.5).maximum(left[:, None])).clamp(0, 1)
        out[:, t, 12:18] = 0.6 * coverage[:, None, :, None]
    return out


def test_track_network_shapes_padding_and_old_configs():
    torch.manual_seed(5)
    model = PhysicsPredictor(TRACK).eval()
    assert model.track is not None and not hasattr(model, "encoder")
    clip = _sliding_square(torch.tensor([0.5, 2.0]))
    out = model(clip)
    assert out["unit"].shape == (2, 4) and ((out["unit"] > 0) & (out["unit"] < 1)).all()
    short = model(clip[:, :5])["unit"]  # fewer frames than num_frames: padded, not refused
    assert short.shape == (2, 4) and torch.isfinite(short).all()
    with pytest.raises(ValueError, match="at most 8"):
        model(torch.rand(1, 9, 32, 32, 3))
    with pytest.raises(ValueError, match="inputs"):
        PhysicsPredictor(PredictorConfig(inputs="pixels"))
    legacy = {k: v for k, v in TINY.to_dict().items() if k not in ("inputs", "track_channels")}
    assert PhysicsPredictor(PredictorConfig.from_dict(legacy)).track is None
    loaded = PhysicsPredictor(PredictorConfig.from_dict(TRACK.to_dict()))
    loaded.load_state_dict(model.state_dict())  # BatchNorm's statistics travel with the weights
    torch.testing.assert_close(loaded.eval()(clip)["unit"], out["unit"])


def test_track_network_learns_a_sub_pixel_slide():
    """Regress how far a square slid (0–1.5 px at 32 px) from the track alone: after 150 Adam
    steps on 64 clips its error on 40 others is under a third of the mean guess' — what a CNN
    that strides to 4×4 maps cannot see, the coverage-weighted moments keep."""
    torch.manual_seed(6)
    model = PhysicsPredictor(TRACK)
    optimizer = torch.optim.Adam(model.parameters(), 3e-3)
    seen = torch.rand(64) * 1.5
    clips = _sliding_square(seen)
    for _ in range(150):
        out = model(clips)
        loss = (out["unit"][:, 3] - seen / 1.5).abs().mean()  # the friction output, in [0, 1]
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    model.eval()
    distance = torch.linspace(0, 1.5, 40)
    with torch.no_grad():
        predicted = model(_sliding_square(distance))["unit"][:, 3] * 1.5
    error = (predicted - distance).abs().mean()
    trivial = (distance - distance.mean()).abs().mean()
    assert error < trivial / 3, (float(error), float(trivial))


def test_scale_head_leaves_the_answer_alone_and_learns_the_error():
    """model.scale_head: the same seed gives the same answer with or without it; its Laplace
    loss sends no gradient into the answer's weights, only into the scale head; the loss is
    lowest at b = the mean |error| (the minimiser of |e| / b + log b); the softplus floor is in
    the observables' natural units; an ensemble's scale is its members' mean."""
    from dataclasses import replace

    from reconphys.models.physics_predictor import PredictorEnsemble, observable_scale
    from reconphys.physics.model import observable_bounds
    from reconphys.train.objective import observable_scale_loss

    with_scale = replace(TRACK, scale_head=True)
    clip = _sliding_square(torch.tensor([0.5, 1.0, 2.0]))
    torch.manual_seed(7)
    plain = PhysicsPredictor(TRACK).eval()
    torch.manual_seed(7)
    scaled = PhysicsPredictor(with_scale).eval()
    out = scaled(clip)
    torch.testing.assert_close(out["unit"], plain(clip)["unit"])
    assert out["observable_scale"].shape == (3, 3) and (out["observable_scale"] > 0).all()
    assert "observable_scale" not in plain(clip)

    scaled.train()
    out = scaled(clip)
    true = torch.tensor([[1.0, 300.0, 1.0, 0.4]] * 3)
    observable_scale_loss(out, out["observable_scale"], true).backward()
    answer = [n for n, p in scaled.named_parameters() if not n.startswith("scale.")]
    assert all(scaled.get_parameter(n).grad is None for n in answer)
    assert all(p.grad is not None for p in scaled.scale.parameters())

    # the loss's minimum: b = mean |e| (in the observables' own units)
    errors = torch.tensor([0.1, 0.3, 0.5, 0.9], dtype=torch.float64)
    width = observable_bounds()[:, 1] - observable_bounds()[:, 0]

    def loss_at(b: float) -> float:
        attributes = {"mass": torch.ones(4), "stiffness": torch.full((4,), 300.0),
                      "damping": torch.ones(4), "friction": 0.5 + errors.float() / 2}  # fmt: skip
        truth = torch.tensor([[1.0, 300.0, 1.0, 0.5]] * 4)
        scale = torch.tensor([[1.0, 1.0, b]] * 4) * width.float()
        return float(observable_scale_loss(attributes, scale, truth))

    best = float((errors / 2).mean())  # friction errors 0.05–0.45: mean 0.225
    assert loss_at(best) < min(loss_at(best * 0.7), loss_at(best * 1.4))

    # softplus floor and natural units
    tiny = observable_scale(torch.full((1, 3), -50.0))
    torch.testing.assert_close(tiny[0], 1e-3 * width.float(), rtol=1e-4, atol=0)

    # an ensemble averages its members' scales
    torch.manual_seed(8)
    ensemble = PredictorEnsemble(with_scale, 2).eval()
    out = ensemble(clip)
    mean = torch.stack([m(clip)["observable_scale"] for m in ensemble.members]).mean(0)
    torch.testing.assert_close(out["observable_scale"], mean)
