"""``lathe-render`` end to end: EXR + PNG written, clear errors."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from conftest import ROOT, SCENES, VARIANT

from lathe_shape.tools.images import read_exr


def run_cli(*args: str) -> subprocess.CompletedProcess:
    """``lathe-render ARGS`` in the test suite's variant (an explicit
    ``--variant`` later in ARGS wins)."""
    return subprocess.run(
        [sys.executable, "-m", "lathe_shape.cli.render", "--variant", VARIANT, *args],
        capture_output=True, text=True, timeout=300,
    )


def test_render_writes_exr_and_png(tmp_path):
    out = tmp_path / "brandy_bottle.exr"
    result = run_cli(str(SCENES / "brandy_bottle.xml"), "-o", str(tmp_path), "--spp", "2",
                     "--resolution", "40x30", "-D", "mesh_segments=32", "--seed", "3")
    assert result.returncode == 0, result.stderr
    assert "40x30, 2 spp" in result.stdout and "rendered in" in result.stdout
    pixels, header = read_exr(out)
    assert pixels.shape == (30, 40, 3) and np.isfinite(pixels).all() and pixels.mean() > 0
    assert header["spp"] == 2 and header["seed"] == 3
    assert (tmp_path / "brandy_bottle.png").stat().st_size > 0


def test_errors(tmp_path):
    missing = run_cli(str(tmp_path / "nope.xml"))
    assert missing.returncode == 2
    assert f"scene file '{tmp_path / 'nope.xml'}' not found" in missing.stderr
    bad_xml = tmp_path / "bad.xml"
    bad_xml.write_text("<scene version='3.0.0'><shape type='lathe'/></scene>")
    bad = run_cli(str(bad_xml), "-o", str(tmp_path))
    assert bad.returncode == 2 and "give exactly one of the parameters 'filename' and 'profile'" in bad.stderr
    assert "Traceback" not in bad.stderr
    define = run_cli(str(SCENES / "wine_glass.xml"), "-D", "spp")
    assert define.returncode == 2 and "-D expects key=value, got 'spp'" in define.stderr
    variant = run_cli(str(SCENES / "wine_glass.xml"), "--variant", "nope")
    assert variant.returncode == 2 and "unknown variant 'nope'" in variant.stderr
    res = run_cli(str(SCENES / "wine_glass.xml"), "--resolution", "axb")
    assert res.returncode == 2 and "resolution must look like 640x480 or 512, got 'axb'" in res.stderr


NO_INTEGRATOR = """<scene version="3.0.0">
    <sensor type="perspective">
        <transform name="to_world"><lookat origin="0,-6,3" target="0,0,1" up="0,0,1"/></transform>
        <film type="hdrfilm"><integer name="width" value="16"/><integer name="height" value="12"/></film>
    </sensor>
    <emitter type="constant"/>
    <shape type="lathe" id="g"><string name="profile" value="0 0, 1 0, 1 2, 0 2"/></shape>
</scene>"""


def test_scene_without_integrator_uses_path(tmp_path):
    scene = tmp_path / "noint.xml"
    scene.write_text(NO_INTEGRATOR)
    result = run_cli(str(scene), "-o", str(tmp_path), "--spp", "1")
    assert result.returncode == 0, result.stderr
    assert "integrator PathIntegrator" in result.stdout
    pixels, _ = read_exr(tmp_path / "noint.exr")
    assert pixels.shape == (12, 16, 3) and pixels.mean() > 0


def test_more_errors(tmp_path):
    folder = run_cli(str(tmp_path))
    assert folder.returncode == 2 and f"'{tmp_path}' is a folder, not a scene file" in folder.stderr
    scene = tmp_path / "noint.xml"
    scene.write_text(NO_INTEGRATOR)
    (tmp_path / "taken").write_text("a file")
    taken = run_cli(str(scene), "-o", str(tmp_path / "taken"))
    assert taken.returncode == 2
    assert f"output folder '{tmp_path / 'taken'}' exists and is not a folder" in taken.stderr
    bad = tmp_path / "bad.xml"
    bad.write_text(NO_INTEGRATOR.replace("0 0, 1 0, 1 2, 0 2", "0 0, 1 0, 1 2, 0.5 2"))
    res = run_cli(str(bad), "--resolution", "8x8", "-o", str(tmp_path))
    assert res.returncode == 2 and f"At {bad} (line" in res.stderr and "profile is not closed" in res.stderr


COMMANDS = ["lathe_shape.cli.render", "lathe_shape.cli.turntable", "lathe_shape.cli.compare"]
SCRIPTS = ["bench_polyline.py", "bench_spline.py", "furnace.py", "validate_against_mesh.py"]


@pytest.mark.parametrize("command", COMMANDS + SCRIPTS)
def test_help(command):
    """Every command's and script's --help runs (and names the shared options)."""
    where = ["-m", command] if command in COMMANDS else [str(ROOT / "scripts" / command)]
    result = subprocess.run([sys.executable, *where, "--variant", VARIANT, "--help"],
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    for option in ("--spp", "--resolution", "--variant"):
        assert option in result.stdout


def test_default_output_folders(tmp_path, monkeypatch):
    """Without -o, lathe-turntable and lathe-compare write to SCENE_turntable
    and SCENE_compare in the current folder."""
    from lathe_shape.cli import compare, turntable

    monkeypatch.chdir(tmp_path)
    small = ["--variant", VARIANT, "--spp", "1", "--resolution", "12x10", "-D", "mesh_segments=16"]
    assert turntable.main([str(SCENES / "wine_glass.xml"), "--count", "1", *small]) == 0
    assert (tmp_path / "wine_glass_turntable" / "frame_0000.exr").is_file()
    assert compare.main([str(SCENES / "wine_glass.xml"), *small]) == 0
    assert (tmp_path / "wine_glass_compare" / "diff.png").is_file()
