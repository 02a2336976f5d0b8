"""``lathe-render`` end to end: EXR + PNG written, clear errors."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
from conftest import SCENES

from lathe_shape.imageio import read_exr


def run_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "lathe_shape.cli.render", *args],
        capture_output=True, text=True, timeout=300,
    )


def test_render_writes_exr_and_png(tmp_path):
    out = tmp_path / "bottle.exr"
    result = run_cli(str(SCENES / "brandy_bottle.xml"), "-o", str(out), "--spp", "2",
                     "--resolution", "40x30", "-D", "mesh_segments=32", "--seed", "3")
    assert result.returncode == 0, result.stderr
    assert "40x30, 2 spp" in result.stdout and "rendered in" in result.stdout
    pixels, header = read_exr(out)
    assert pixels.shape == (30, 40, 3) and np.isfinite(pixels).all() and pixels.mean() > 0
    assert header["spp"] == 2 and header["seed"] == 3
    assert (tmp_path / "bottle.png").stat().st_size > 0


def test_errors(tmp_path):
    missing = run_cli(str(tmp_path / "nope.xml"))
    assert missing.returncode == 2
    assert f"scene file '{tmp_path / 'nope.xml'}' not found" in missing.stderr
    bad_xml = tmp_path / "bad.xml"
    bad_xml.write_text("<scene version='3.0.0'><shape type='lathe'/></scene>")
    bad = run_cli(str(bad_xml), "-o", str(tmp_path / "x.exr"))
    assert bad.returncode == 2 and "give exactly one of the parameters 'filename' and 'profile'" in bad.stderr
    assert "Traceback" not in bad.stderr
    define = run_cli(str(SCENES / "wine_glass.xml"), "-D", "spp")
    assert define.returncode == 2 and "-D expects key=value, got 'spp'" in define.stderr
    variant = run_cli(str(SCENES / "wine_glass.xml"), "--variant", "nope")
    assert variant.returncode == 2 and "unknown variant 'nope'" in variant.stderr
    res = run_cli(str(SCENES / "wine_glass.xml"), "--resolution", "axb")
    assert res.returncode == 2 and "resolution must look like 640x480 or 512, got 'axb'" in res.stderr
