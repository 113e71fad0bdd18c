"""Pretrained encoders from local files: a tiny randomly initialised ViT saved to a folder plays
the pretrained checkpoint (never downloaded); timm runs where it is installed (extra
``pretrained``)."""

from __future__ import annotations

import pytest
import torch
from safetensors.torch import load_file

from reconphys.errors import InputError
from reconphys.models.physics_predictor import PhysicsPredictor, PredictorConfig
from reconphys.models.pretrained import tokens_to_map
from reconphys.models.shipped import load_predictor, model_metadata, save_predictor

transformers = pytest.importorskip("transformers")


@pytest.fixture(scope="module")
def vit_folder(tmp_path_factory):
    config = transformers.ViTConfig(
        image_size=32, patch_size=8, num_channels=3, hidden_size=16, num_hidden_layers=1,
        num_attention_heads=2, intermediate_size=32,
    )  # fmt: skip
    torch.manual_seed(0)
    folder = tmp_path_factory.mktemp("tiny_vit")
    transformers.ViTModel(config, add_pooling_layer=False).save_pretrained(folder)
    return folder


def _config(folder, **extra) -> PredictorConfig:
    return PredictorConfig(
        encoder="transformers", encoder_channels=(), token_channels=8, trunk_blocks=1,
        attention_heads=2, mlp_hidden=(8,), num_frames=3, resolution=32,
        extra={"path": str(folder), **extra},
    )  # fmt: skip


def test_tokens_fold_back_to_the_patch_grid():
    grid = torch.arange(2 * 5 * 4, dtype=torch.float32).reshape(2, 5, 4)  # 1 prefix + 2×2 patches
    out = tokens_to_map(grid, prefix=1)
    assert out.shape == (2, 4, 2, 2)
    assert torch.equal(out[:, :, 1, 0], grid[:, 3])  # row-major patches after the prefix
    with pytest.raises(ValueError, match="square grid"):
        tokens_to_map(grid, prefix=2)


def test_transformers_encoder_loads_the_local_weights(vit_folder):
    model = PhysicsPredictor(_config(vit_folder))
    saved = load_file(str(vit_folder / "model.safetensors"))  # read directly, not through HF
    ours = model.encoder.backbone.state_dict()
    common = set(saved) & set(ours)  # file and module names differ for some layers
    assert {"embeddings.cls_token", "embeddings.patch_embeddings.projection.weight"} <= common
    for name in common:
        value = saved[name]
        torch.testing.assert_close(ours[name], value, rtol=0, atol=0)  # the folder's, not random
    frames = torch.rand(2, 3, 32, 32, 3)
    out = model(frames)
    assert out["unit"].shape == (2, 4) and torch.isfinite(out["unit"]).all()
    features = model.encoder(frames[:, 0].permute(0, 3, 1, 2))
    assert features.shape == (2, 16, 4, 4) and model.encoder.prefix == 1  # [CLS] dropped
    out["unit"].sum().backward()  # fine-tunable end to end
    assert model.encoder.backbone.embeddings.patch_embeddings.projection.weight.grad is not None


def test_trained_predictor_round_trip(vit_folder, tmp_path):
    config = _config(vit_folder)
    torch.manual_seed(1)
    model = PhysicsPredictor(config)
    with torch.no_grad():  # "training" changed the backbone: the saved model must carry it
        model.encoder.backbone.embeddings.cls_token.add_(1.0)
    path = save_predictor(model, tmp_path / "m.safetensors", model_metadata(config, 0, 0.03))
    loaded = load_predictor(path)
    frames = torch.rand(1, 3, 32, 32, 3)
    with torch.no_grad():
        expected = model.eval()(frames)["unit"]
    torch.testing.assert_close(loaded.predict(frames)["unit"], expected, rtol=0, atol=1e-6)


def test_bad_local_sources_are_one_line_errors(tmp_path):
    with pytest.raises(InputError, match=r"no config\.json") as error:
        PhysicsPredictor(_config(tmp_path / "missing"))
    assert "missing" in str(error.value) and "\n" not in str(error.value)
    (tmp_path / "broken").mkdir()
    (tmp_path / "broken" / "config.json").write_text('{"model_type": "vit"}')  # no weights
    with pytest.raises(InputError, match="cannot load the model"):
        PhysicsPredictor(_config(tmp_path / "broken"))
    with pytest.raises(InputError, match="model folder"):
        PhysicsPredictor(_config("", path=""))


def test_timm_encoder_builds_from_a_local_file(tmp_path):
    timm = pytest.importorskip("timm")
    backbone = timm.create_model("resnet18", pretrained=False, num_classes=0)
    from safetensors.torch import save_file

    weights = tmp_path / "resnet18.safetensors"
    save_file({k: v.contiguous() for k, v in backbone.state_dict().items()}, str(weights))
    config = PredictorConfig(
        encoder="timm", token_channels=8, trunk_blocks=1, attention_heads=2, mlp_hidden=(8,),
        num_frames=2, resolution=32, extra={"name": "resnet18", "weights": str(weights)},
    )  # fmt: skip
    model = PhysicsPredictor(config)
    for name, value in backbone.state_dict().items():
        torch.testing.assert_close(model.encoder.backbone.state_dict()[name], value)
    assert model(torch.rand(1, 2, 32, 32, 3))["unit"].shape == (1, 4)
    with pytest.raises(InputError, match="weights file not found"):
        PhysicsPredictor(
            PredictorConfig(encoder="timm", extra={"name": "resnet18", "weights": "nope.pt"})
        )
