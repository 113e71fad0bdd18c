"""The one settings loader: files → dataclasses, typed overrides, errors naming file and key."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import pytest

from reconphys.config_loader import check_type, load_settings, parse_value, read_table
from reconphys.data.settings import PRESETS, make_settings
from reconphys.errors import InputError

CONFIGS = Path(__file__).resolve().parent.parent / "configs"


@dataclass(frozen=True)
class Settings:
    name: str
    steps: int = 10
    rate: float = 0.5
    pair: tuple[float, float] = (0.0, 1.0)


def test_layers_apply_in_order_with_types(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text('name = "a"\nsteps = 3\nrate = 1\npair = [2, 3]\n')
    settings = load_settings(Settings, (read_table(path), str(path)), ({"steps": 4}, None))
    assert settings == Settings("a", 4, 1.0, (2.0, 3.0)) and isinstance(settings.rate, float)
    assert load_settings(Settings, ({"steps": 5}, None), base=Settings("b")).name == "b"


@pytest.mark.parametrize(
    ("table", "message"),
    [
        ({"nme": "a"}, "s.toml [nme]: unknown key (known: name, steps, rate, pair)"),
        ({"name": "a", "steps": 2.5}, "s.toml [steps]: expected an integer, got 2.5"),
        ({"name": "a", "pair": [1]}, "s.toml [pair]: expected 2 values"),
        ({"steps": 2}, "name: missing"),
    ],
)
def test_errors_name_the_file_and_key(table, message):
    with pytest.raises(InputError) as error:
        load_settings(Settings, (table, "s.toml"))
    assert message in str(error.value)


def test_override_text_is_parsed_for_the_field_type():
    assert parse_value("3e-4", float) == 3e-4 and parse_value("[1, 2]", tuple) == [1, 2]
    assert parse_value("123", str) == "123" and parse_value('"x"', str) == "x"
    assert check_type(True, bool, "k") is True
    with pytest.raises(InputError, match="expected true or false"):
        check_type(1, bool, "k")


def test_data_presets_and_config_files():
    paper = make_settings("paper")
    assert (paper.objects, paper.resolution, paper.num_anchors) == (450, 512, 2048)
    assert make_settings("small") == PRESETS["small"]
    small = make_settings(config=CONFIGS / "data_small.toml")
    flags = make_settings(
        objects=40,
        test_objects=6,
        samples_per_object=6,
        test_samples_per_object=2,
        resolution=32,
        toss_fraction=0.0,
    )
    assert small == flags and small.fingerprint() == flags.fingerprint()
    # flags win over the file, the file over the preset
    assert make_settings("paper", CONFIGS / "data_small.toml", objects=3).num_anchors == 2048
    assert make_settings("paper", CONFIGS / "data_small.toml", objects=3).objects == 3
