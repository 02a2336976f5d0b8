"""POV-Ray export: the exact B-spline -> Bezier conversion, the generated
scene, and (when povray is installed) a tiny end-to-end comparison."""

from __future__ import annotations

import re
import shutil

import numpy as np
import pytest
from conftest import ROOT, VARIANT

from lathe_shape.profiles import bspline as bs
from lathe_shape.tools.povray_export import bezier_evaluate, bspline_to_bezier, lathe_spline, scene_to_pov
from lathe_shape.tools.scenes import load_scene


def test_bspline_to_bezier_is_exact():
    rng = np.random.default_rng(5)
    controls = np.column_stack([rng.uniform(0.5, 2.0, 9), np.cumsum(rng.uniform(0.2, 1.0, 9))])
    controls = np.vstack([[0.0, -0.5], controls, [0.0, controls[-1, 1] + 0.5]])
    segments = bs.bspline_segments(controls)
    bezier = bspline_to_bezier(segments)
    index = np.repeat(np.arange(len(segments)), 50)
    t = np.tile(np.linspace(0.0, 1.0, 50), len(segments))
    r, z = bs.evaluate(segments, index, t)
    assert np.abs(bezier_evaluate(bezier, index, t) - np.column_stack([r, z])).max() < 1e-12
    # Consecutive Bezier segments join: the curve is one piece.
    assert np.abs(bezier[1:, 0] - bezier[:-1, 3]).max() < 1e-12


@pytest.mark.parametrize(("figure", "spline"), [("fig9", "linear_spline"), ("fig8b", "bezier_spline")])
def test_pov_scene_holds_the_lathe(figure, spline):
    from lathe_shape.plugin.shape import scene_lathes

    scene = load_scene(ROOT / "scenes" / "paper" / f"{figure}.xml", {"res": "8", "spp": "1"})
    lathe = scene_lathes(scene)[0]
    kind, points = lathe_spline(lathe)
    segments = lathe.profile.segment_count
    expected = 4 * segments if spline == "bezier_spline" else segments + 1
    assert kind == spline and len(points) == expected
    text = scene_to_pov(scene)
    match = re.search(rf"lathe {{ {spline} (\d+), ", text)
    assert match and int(match.group(1)) == expected
    assert text.count("light_source") >= 1 and "camera { perspective" in text


@pytest.mark.skipif(shutil.which("povray") is None, reason="povray (Debian package) is not installed")
@pytest.mark.povray
def test_compare_povray_end_to_end(tmp_path, capsys):
    import importlib.util

    spec = importlib.util.spec_from_file_location("compare_povray", ROOT / "scripts" / "compare_povray.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    out = tmp_path / "cmp out"  # (a space: POV-Ray split its +I option there)
    rc = module.main([str(ROOT / "scenes" / "paper" / "fig9.xml"), "--resolution", "32x24", "--spp", "1",
                      "-o", str(out), "--variant", VARIANT, "--max-depth", "4"])
    assert rc == 0
    last = capsys.readouterr().out.strip().splitlines()[-1]
    assert re.fullmatch(r"povray \d+\.\d\d s, lathe_whitted \d+\.\d\d s, ratio \d+\.\d\dx", last), last
    for name in ("scene.pov", "povray.exr", "lathe_whitted.exr", "sheet.png"):
        assert (out / name).is_file(), name
    # lathe_whitted's depth counts the segment to the light, POV-Ray's level does not
    assert "max_trace_level 3 " in (out / "scene.pov").read_text()
    assert module.main([str(ROOT / "scenes" / "paper" / "fig9.xml"), "-o", str(out), "--max-depth", "1",
                        "--variant", VARIANT]) == 2


def test_compare_povray_help_and_errors(tmp_path):
    import subprocess
    import sys

    script = str(ROOT / "scripts" / "compare_povray.py")
    proc = subprocess.run([sys.executable, script, "--help"], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0 and "-o DIR, --output DIR" in proc.stdout and "--spp" in proc.stdout
    scene = tmp_path / "cylinder.xml"
    scene.write_text('<scene version="3.0.0"><sensor type="perspective"><film type="hdrfilm">'
                     '<integer name="width" value="8"/><integer name="height" value="8"/></film></sensor>'
                     '<shape type="cylinder"/><emitter type="point"/></scene>')
    command = [sys.executable, script, str(scene), "-o", str(tmp_path / "o"), "--variant", VARIANT]
    proc = subprocess.run(command, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2
    assert f"{scene}: a Cylinder shape: shape 'Cylinder' has no POV-Ray counterpart here" in proc.stderr
