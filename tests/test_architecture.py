"""The package layers (docs/design.md#package-layers) are kept by import-linter, not by hand.

`make test` runs `lint-imports` on the package; these tests show the contracts in pyproject.toml
hold on the package as it is and break when an upward import is added (a copy of the package
where ``physics`` imports the viewer, and one where ``train`` imports ``pipeline``).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("importlinter")

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "src" / "reconphys"


def lint_imports(package_parent: Path, cache: Path) -> subprocess.CompletedProcess:
    """Run import-linter with the project's contracts on the package found in package_parent."""
    env = dict(os.environ, PYTHONPATH=str(package_parent))
    script = "from importlinter.cli import lint_imports_command; lint_imports_command()"
    return subprocess.run(
        [sys.executable, "-c", script, str(ROOT / "pyproject.toml"), "--cache-dir", str(cache)],
        cwd=package_parent,
        env=env,
        capture_output=True,
        text=True,
        timeout=300,
    )


def test_contracts_hold_on_the_package(tmp_path):
    result = lint_imports(ROOT / "src", tmp_path / "cache")
    assert result.returncode == 0, result.stdout + result.stderr


@pytest.mark.parametrize(
    ("module", "upward_import", "broken"),
    [
        ("physics/model.py", "from reconphys.viewer import app  # noqa", "Layers"),
        ("train/__init__.py", "import reconphys.pipeline.predict  # noqa", "Layers"),
    ],
)
def test_an_upward_import_breaks_the_contracts(tmp_path, module, upward_import, broken):
    copy = tmp_path / "src" / "reconphys"
    shutil.copytree(PACKAGE, copy, ignore=shutil.ignore_patterns("__pycache__", "weights"))
    with open(copy / module, "a") as f:
        f.write(f"\n{upward_import}\n")
    result = lint_imports(tmp_path / "src", tmp_path / "cache")
    assert result.returncode != 0
    assert "BROKEN" in result.stdout and broken in result.stdout, result.stdout
