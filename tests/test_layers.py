"""The package's layers, as pyproject.toml's import-linter contract states
them (validation > cli : distributed > tools > plugin > surfaces > kernels >
profiles > memory | tessellate): ``lint-imports`` passes on the package, and
fails, naming the import, on a copy with one deliberate upward import."""

from __future__ import annotations

import ast
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10 (import-linter brings tomli)
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "lathe_shape"


def lint_imports(cwd: Path) -> subprocess.CompletedProcess:
    """``lint-imports`` run in ``cwd`` (its pyproject.toml, its package)."""
    script = Path(sys.executable).parent / "lint-imports"
    if not script.exists():
        found = shutil.which("lint-imports")
        if found is None:
            pytest.fail("lint-imports not found: pip install -e '.[test]' (import-linter)")
        script = Path(found)
    env = dict(os.environ, PYTHONPATH=str(cwd))  # the copy's package, not the installed one
    return subprocess.run([str(script), "--no-cache"], cwd=cwd, env=env, capture_output=True,
                          text=True, timeout=120)


def contract_layers() -> list[str]:
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]
    (contract,) = [c for c in config["contracts"] if c["type"] == "layers"]
    return contract["layers"]


def test_the_package_keeps_its_layers():
    result = lint_imports(ROOT)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "BROKEN" not in result.stdout


def test_an_upward_import_breaks_the_contract(tmp_path):
    shutil.copytree(PACKAGE, tmp_path / "lathe_shape", ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(ROOT / "pyproject.toml", tmp_path)
    lint_imports(tmp_path).check_returncode()  # the copy itself is fine
    polyline = tmp_path / "lathe_shape" / "kernels" / "polyline.py"
    polyline.write_text(polyline.read_text() + "\nimport lathe_shape.cli  # deliberately upward\n")
    result = lint_imports(tmp_path)
    assert result.returncode != 0
    assert "BROKEN" in result.stdout
    assert "lathe_shape.kernels.polyline -> lathe_shape.cli" in result.stdout, result.stdout


def test_every_top_level_module_has_a_layer():
    """A new module or subpackage of lathe_shape is placed in the contract
    (the root lathe_shape/__init__.py, the facade, is in none)."""
    named = {name.strip() for layer in contract_layers() for name in layer.replace("|", ":").split(":")}
    modules = {f"lathe_shape.{p.stem}" for p in PACKAGE.glob("*.py") if p.stem != "__init__"}
    modules |= {f"lathe_shape.{p.parent.name}" for p in PACKAGE.glob("*/__init__.py")}
    assert modules - named == set(), "add these to [tool.importlinter] in pyproject.toml"
    assert named - modules == set()


def test_variants_is_a_leaf():
    """plugin/variants.py imports nothing of the package: the plugin modules
    import it, and plugin/__init__.py's register() imports them."""
    tree = ast.parse((PACKAGE / "plugin" / "variants.py").read_text())
    imports = [node for node in ast.walk(tree) if isinstance(node, ast.Import | ast.ImportFrom)]
    names = [alias.name for node in imports if isinstance(node, ast.Import) for alias in node.names]
    relative = [node.module for node in imports if isinstance(node, ast.ImportFrom) and node.level]
    absolute = [node.module for node in imports if isinstance(node, ast.ImportFrom) and not node.level]
    assert relative == []
    assert [n for n in names + absolute if n and n.split(".")[0] == "lathe_shape"] == []
