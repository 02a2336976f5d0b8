"""End-to-end runs of scripts/reproduce_paper.py --quick and lathe-compare."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from conftest import ROOT, VARIANT
from PIL import Image


@pytest.mark.slow
def test_reproduce_paper_quick(tmp_path):
    out = tmp_path / "paper"
    proc = subprocess.run(
        [sys.executable, str(ROOT / "scripts" / "reproduce_paper.py"), "--quick", "-o", str(out),
         "--variant", VARIANT],
        capture_output=True, text=True, timeout=300, cwd=str(ROOT))
    assert proc.returncode == 0, proc.stderr[-3000:]
    text = proc.stdout
    expected = {"fig8a": ("polyline", 31), "fig8b": ("bspline", 12), "fig9": ("polyline", 42),
                "fig10a": ("polyline", 58), "fig10b": ("polyline", 86)}
    for fig, (method, n) in expected.items():
        row = next(line for line in text.splitlines() if line.startswith(fig + " "))
        assert method in row and f" {n} " in row, row
        assert (out / f"{fig}.exr").is_file() and (out / f"{fig}.png").is_file()
    assert "spline/polyline time ratio" in text
    assert (out / "table.txt").is_file()
    sheet = Image.open(out / "sheet_fig8a_8b_9.png")
    assert sheet.size[0] >= 3 * 48
    for name in ("glass", "glass_fig9", "sundae_cup", "brandy_bottle"):
        assert (out / f"reference_{name}.exr").is_file()


@pytest.mark.parametrize("script", ["reproduce_paper.py", "open_problems.py", "make_profiles.py"])
def test_script_help(script):
    proc = subprocess.run([sys.executable, str(ROOT / "scripts" / script), "--help"],
                          capture_output=True, text=True, timeout=120, cwd=str(ROOT))
    assert proc.returncode == 0 and "-o DIR, --output DIR" in proc.stdout, proc.stderr[-2000:]


def test_lathe_compare(tmp_path):
    from lathe_shape.cli.compare import main
    from lathe_shape.tools.images import read_exr

    out = tmp_path / "cmp"
    rc = main([str(ROOT / "scenes" / "paper" / "fig9.xml"), "-o", str(out), "--spp", "2",
               "--resolution", "24x20", "--mesh-segments", "64", "--variant", VARIANT])
    assert rc == 0
    for name in ("exact.exr", "exact.png", "mesh.exr", "mesh.png", "diff.png"):
        assert (out / name).is_file(), name
    exact, header = read_exr(out / "exact.exr")
    mesh, _ = read_exr(out / "mesh.exr")
    assert exact.shape == (20, 24, 3) and header["integrator"] == "lathe_path"
    # Same seed, correlated noise: the two renders are close.
    assert np.abs(mesh - exact).mean() / exact.mean() < 0.2
    diff = np.asarray(Image.open(out / "diff.png"))
    assert diff.shape[1] == 24 and diff.shape[0] > 20  # colour bar below


def test_lathe_compare_errors(tmp_path, capsys):
    from lathe_shape.cli.compare import main

    assert main([str(tmp_path / "none.xml"), "-o", str(tmp_path), "--variant", VARIANT]) == 2
    assert "not found" in capsys.readouterr().err
    assert main([str(ROOT / "scenes" / "paper" / "fig9.xml"), "-o", str(tmp_path), "--spp", "0",
                 "--variant", VARIANT]) == 2
    assert "--spp" in capsys.readouterr().err
    floor_only = tmp_path / "floor.xml"
    floor_only.write_text('<scene version="3.0.0"><sensor type="perspective"><film type="hdrfilm">'
                          '<integer name="width" value="8"/><integer name="height" value="8"/></film>'
                          '</sensor><shape type="rectangle"/></scene>')
    assert main([str(floor_only), "-o", str(tmp_path / "o"), "--variant", VARIANT]) == 2
    assert "no lathe" in capsys.readouterr().err


@pytest.mark.parametrize("script", ["reproduce_paper.py", "open_problems.py"])
def test_seed_out_of_range_is_one_line(tmp_path, script):
    """--seed -1 gave nanobind's TypeError from deep in the render."""
    proc = subprocess.run([sys.executable, str(ROOT / "scripts" / script), "--quick", "--seed", "-1", "-o",
                           str(tmp_path / "o"), "--variant", VARIANT],
                          capture_output=True, text=True, timeout=300, cwd=str(ROOT))
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines()[-1] == f"{script}: error: --seed must be at least 0, got -1"
