"""The scripts' command-line convention: inverse_design.py writes to
-o/--output and takes WxH; bench_turntable.py finds its scene from any
folder and refuses a bad one in one line; the leak tests' options."""

from __future__ import annotations

import importlib.util
import os
import subprocess
import sys

import pytest
from conftest import ROOT, VARIANT

from lathe_shape.cli.common import DEFAULT_VARIANT
from lathe_shape.validation import leaks
from lathe_shape.validation.turntable_bench import bench_parser


def load_script(name: str):
    """A script of scripts/ as a module (its ``main`` not run)."""
    spec = importlib.util.spec_from_file_location(name.removesuffix(".py"), ROOT / "scripts" / name)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.slow
def test_inverse_design_output_and_resolution(tmp_path, capsys):
    inverse = load_script("inverse_design.py")
    assert inverse.square_resolution("24x24") == 24 and inverse.square_resolution("24") == 24
    code = inverse.main(["--resolution", "16x12", "-o", str(tmp_path / "no"), "--variant", VARIANT])
    assert code == 2 and capsys.readouterr().err == (
        "inverse_design.py: error: --resolution must be square (the views are), got '16x12'\n")
    code = inverse.main(["--resolution", "4", "-o", str(tmp_path / "no"), "--variant", VARIANT])
    assert code == 2
    assert capsys.readouterr().err == "inverse_design.py: error: --resolution must be at least 8, got 4\n"
    code = inverse.main(["--kind", "hollow", "--silhouette-weight", "-1", "-o", str(tmp_path / "no"),
                         "--variant", VARIANT])
    assert code == 2
    assert capsys.readouterr().err == "inverse_design.py: error: --silhouette-weight must be >= 0, got -1\n"
    code = inverse.main(["--kind", "hollow", "--uphill", "nan", "-o", str(tmp_path / "no"),
                         "--variant", VARIANT])
    assert code == 2
    assert capsys.readouterr().err == "inverse_design.py: error: --uphill must be finite, got nan\n"
    assert not (tmp_path / "no").exists()
    out = tmp_path / "out"
    code = inverse.main(["--iterations", "1", "--resolution", "8", "--spp", "1", "-o", str(out),
                         "--variant", VARIANT])
    assert code == 0, capsys.readouterr().err
    written = sorted(os.listdir(out))
    assert written == sorted(["convergence.png", *(f"view_{k}_{name}.png" for k in range(2)
                                                   for name in ("target", "before", "after"))])


def test_bench_turntable_scene_from_any_folder(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    args = bench_parser().parse_args([])
    assert os.path.samefile(args.scene, ROOT / "scenes" / "wine_glass.xml") and args.resolution == 128
    assert bench_parser().parse_args(["--resolution", "64x64"]).resolution == 64


@pytest.mark.parametrize("content, message", [
    (None, "scene file 'nope.xml' not found"),
    ("<scene version='3.0.0'><shape type='lathe'>",
     "nope.xml: not a valid XML file (no element found: line 1"),
    ("<scene version='3.0.0'><shape type='sphere'/></scene>",
     "nope.xml: the scene has no <shape type=\"lathe\"> to turn"),
])
def test_bench_turntable_bad_scene(tmp_path, monkeypatch, capsys, content, message):
    monkeypatch.chdir(tmp_path)
    if content is not None:
        (tmp_path / "nope.xml").write_text(content)
    with pytest.raises(SystemExit) as exit_info:
        bench_parser().parse_args(["--scene", "nope.xml"])
    last = capsys.readouterr().err.splitlines()[-1]
    assert exit_info.value.code == 2
    assert last.startswith(f"bench_turntable.py: error: argument --scene: {message}")


def test_leak_test_options(capsys):
    with pytest.raises(SystemExit):
        leaks.leak_test_arguments("polyline", ["--help"])
    text = " ".join(capsys.readouterr().out.split())
    for option in ("--rays RAYS rays in all (default: 1e6)", f"(default: {DEFAULT_VARIANT})",
                   "(default: 250000)", "(default: 512)", "--random-profiles"):
        assert option in text
    with pytest.raises(SystemExit) as exit_info:
        leaks.leak_test_arguments("bspline", ["--random-profiles"], random_profiles=False)
    assert exit_info.value.code == 2
    assert "unrecognized arguments: --random-profiles" in capsys.readouterr().err


def test_leak_test_bspline_help():
    result = subprocess.run([sys.executable, str(ROOT / "scripts" / "leak_test_bspline.py"), "--help"],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0 and "--rays" in result.stdout and "--random-profiles" not in result.stdout
