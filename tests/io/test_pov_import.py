"""``lathe-profile --from-pov``: the reader of POV-Ray lathe/sor blocks, its
errors, the axis conversion, and the round trip (imported profiles give the
same exact hits as the same curves entered by hand); ``--to-polyline`` for
every kind."""

from __future__ import annotations

import re
import subprocess
import sys

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from lathe_shape.cli import profile as cli
from lathe_shape.profiles.pov import PovError, read_pov_blocks, to_world

SCENE = """// written for the tests
#include "colors.inc"
#declare Vase = lathe {
  bezier_spline
  8,
  <0, 0>, <1.5, 0>, <1.6, 0.3>, <1.6, 1.2>,
  <1.6, 1.2>, <1.6, 2.2>, <0.4, 2.4>, <0, 2.4>
  sturm
  pigment { color rgb <1, 0.5, 0> }
  scale 2 translate <1, 0, 3>
}
/* a block comment with lathe { in it */
#local Goblet = lathe { cubic_spline 7, <0, -0.3>, <0, 0>, <1.1, 0.05>, <0.25, 0.5>,
  <1.2, 1.9>, <0, 1.8>, <0, 1.5> rotate <90, 0, 0> }
lathe { quadratic_spline 4, <0, -1>, <0, 0>, <1, 0.5>, <1.2, 1.5> }
lathe { 3, <0, 0>, <1, 0>, <0, 1> }
sor {
  7, <0, -0.5>, <1.0, 0>, <1.2, 0.5>, <0.6, 1.5>, <0.4, 2.5>, <0.5, 3>, <0.6, 3.5>
  open
  texture { pigment { Red } finish { phong 1 } }
  rotate <0, 30, 0>
}
object { Vase }
"""


@pytest.fixture
def pov_file(tmp_path):
    path = tmp_path / "scene.pov"
    path.write_text(SCENE)
    return path


def test_blocks_are_read(pov_file):
    blocks = read_pov_blocks(pov_file)
    assert [b.name for b in blocks] == ["Vase", "Goblet", "scene_lathe3", "scene_lathe4", "scene_sor1"]
    assert [b.kind for b in blocks] == ["bezier", "catmull_rom", "quadratic", "polyline", "sor"]
    assert [b.open_sheet for b in blocks] == [False, False, True, False, True]
    vase = blocks[0]
    assert vase.sturm and vase.where.endswith("scene.pov:3") and len(vase.points) == 8
    assert any("'pigment' ignored" in n for n in vase.notes)
    np.testing.assert_allclose(vase.transform[:3, :3], 2 * np.eye(3))
    np.testing.assert_allclose(vase.transform[:3, 3], [1, 0, 3])
    np.testing.assert_allclose(blocks[-1].points[2], [1.2, 0.5])


def test_axis_conversion():
    """A POV-Ray lathe point (r, h) at azimuth 0 is (r, h, 0) in its object
    space; the lathe plugin's local point (r, 0, h) must land on the same
    world point with POV-Ray's y and z swapped."""
    rng = np.random.default_rng(3)
    for _ in range(5):
        m = np.eye(4)
        m[:3, :3] = rng.normal(size=(3, 3))
        m[:3, 3] = rng.normal(size=3)
        r, h = rng.uniform(0, 2, 2)
        pov_world = m @ [r, h, 0.0, 1.0]
        mitsuba_world = to_world(m) @ [r, 0.0, h, 1.0]
        np.testing.assert_allclose(mitsuba_world, pov_world[[0, 2, 1, 3]], atol=1e-12)


@pytest.mark.parametrize("text, message", [
    # Issue 28: expressions are evaluated now (the old "expected a literal
    # number" / "expressions are not evaluated" refusals were the bug).
    ("lathe { linear_spline <0, 0>, <1, 1> }",
     "scene.pov:1: expected the point count of the lathe, got a point"),
    ("lathe {\n 4, <0, 0>, <1, 0>, <0, 1> }",
     "scene.pov:2: the lathe announces 4 points but point 4 is missing"),
    ("lathe { 3, <0, 0>, <R, 0>, <0, 1> }", "scene.pov:1: unknown identifier 'R'"),
    ("sor { 4, <0, 0>, <1/0, 0>, <1, 1>, <0, 2> }", "scene.pov:1: division by zero"),
    ("lathe { cubic_splin 4, <0, 0>, <1, 0>, <1, 1>, <0, 1> }", "unknown lathe spline type 'cubic_splin'"),
    ("\n\nlathe { 3, <0, 0>, <1, 0>, <0, 1>\n", "scene.pov:4: the lathe block opened at"),
    ("lathe { 3, <0, 0>, <1, 0, 2>, <0, 1> }", "point 2 of the lathe has 3 components, expected 2"),
    ("lathe { 3, <0, 0>, <1, 0>, <0, 1> open }", "'open' is a sor modifier"),
])
def test_malformed_blocks_name_file_and_line(tmp_path, text, message):
    path = tmp_path / "scene.pov"
    path.write_text(text)
    with pytest.raises(PovError, match=re.escape(message)):
        read_pov_blocks(path)


def _hits(shape, n=3000, seed=0):
    rng = np.random.default_rng(seed)
    lo, hi = (np.array(v) for v in (shape.bbox().min, shape.bbox().max))
    target = rng.uniform(lo, hi, (n, 3))
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    org = target - 3 * np.linalg.norm(hi - lo) * d
    ray = mi.Ray3f(mi.Point3f(org.T.astype(np.float32)), mi.Vector3f(d.T.astype(np.float32)))
    si = shape.ray_intersect_exact(ray)
    dr.eval(si.t)
    return si.t.numpy()


def test_round_trip_gives_the_same_exact_hits(pov_file, tmp_path, capsys):
    out = tmp_path / "out"
    assert cli.main(["--from-pov", str(pov_file), "-o", str(out)]) == 0
    err = capsys.readouterr().err  # each object's notes name it: stderr may be read apart from stdout
    assert f"  note: {pov_file}:3: lathe 'Vase': line 9: 'pigment' ignored" in err, err
    by_hand = {
        "Vase": ("bezier", "0 0, 1.5 0, 1.6 0.3, 1.6 1.2, 1.6 1.2, 1.6 2.2, 0.4 2.4, 0 2.4", False,
                 mi.ScalarTransform4f().translate([1, 3, 0]).scale(2)),
        "Goblet": ("catmull_rom", "0 -0.3, 0 0, 1.1 0.05, 0.25 0.5, 1.2 1.9, 0 1.8, 0 1.5", False,
                   # POV-Ray's rotate about +x is one about Mitsuba's +x, the other way round.
                   mi.ScalarTransform4f().rotate([1, 0, 0], -90)),
        "scene_lathe3": ("quadratic", "0 -1, 0 0, 1 0.5, 1.2 1.5", True, mi.ScalarTransform4f()),
        "scene_lathe4": ("polyline", "0 0, 1 0, 0 1", False, mi.ScalarTransform4f()),
        "scene_sor1": ("sor", "0 -0.5, 1.0 0, 1.2 0.5, 0.6 1.5, 0.4 2.5, 0.5 3, 0.6 3.5", True,
                       # POV-Ray's rotate about +y is one about Mitsuba's +z, the other way round.
                       mi.ScalarTransform4f().rotate([0, 0, 1], -30)),
    }
    for name, (kind, text, open_sheet, transform) in by_hand.items():
        xml = (out / f"{name}.xml").read_text()
        scene = mi.load_string(f"<scene version='3.0.0'>{xml}</scene>".replace(
            'value="' + name + '.csv"', f'value="{out / (name + ".csv")}"'))
        imported = scene.shapes()[0]
        hand = mi.load_dict({"type": "lathe", "kind": kind, "profile": text, "open": open_sheet,
                             "to_world": transform})
        assert imported.surface.kind == kind and imported.profile.open_sheet == open_sheet
        a, b = _hits(imported), _hits(hand)
        assert np.isfinite(a).mean() > 0.05
        assert np.array_equal(np.isfinite(a), np.isfinite(b))
        np.testing.assert_allclose(a[np.isfinite(a)], b[np.isfinite(b)], rtol=1e-5)


def test_csv_declarations_and_conflicts(tmp_path):
    path = tmp_path / "cup.csv"
    path.write_text("# kind: bezier\n# open: true\nr,z\n0,0\n1,0\n1.2,0.5\n1.3,1.5\n")
    shape = mi.load_dict({"type": "lathe", "filename": str(path)})
    assert shape.surface.kind == "bezier" and shape.profile.open_sheet
    with pytest.raises(RuntimeError, match="parameter 'kind' is 'polyline' but the profile file"):
        mi.load_dict({"type": "lathe", "filename": str(path), "kind": "polyline"})
    path.write_text("# open: maybe\n0,0\n1,0\n0,1\n")
    with pytest.raises(RuntimeError, match=r"cup\.csv, line 1: 'open' must be true or false"):
        mi.load_dict({"type": "lathe", "filename": str(path)})


@pytest.mark.parametrize("kind, text, extra", [
    ("bspline", "0,0\n1,0\n1,1\n0,2\n", []),
    ("bezier", "0,0\n1,0\n1.2,0.5\n1.3,1.5\n", ["--open"]),
    ("catmull_rom", "0,-0.3\n0,0\n1.1,0.05\n0.25,0.5\n1.2,1.9\n0,1.8\n0,1.5\n", []),
    ("quadratic", "0,-1\n0,0\n1,0.5\n0.5,2\n0,3\n", []),
    ("sor", "0,-0.5\n1,0\n1.2,0.5\n0.6,1.5\n0.4,2.5\n0.5,3\n0.6,3.5\n", []),
])
def test_to_polyline_for_every_kind(tmp_path, capsys, kind, text, extra):
    path = tmp_path / "p.csv"
    path.write_text(text)
    assert cli.main([str(path), "--kind", kind, *extra]) == 0
    assert f"valid {'cubic B-spline' if kind == 'bspline' else kind} profile" in capsys.readouterr().out
    assert cli.main([str(path), "--kind", kind, *extra, "--to-polyline", "40", "-o", str(tmp_path)]) == 0
    poly = tmp_path / "p_40.csv"
    shape = mi.load_dict({"type": "lathe", "filename": str(poly)})
    assert shape.profile.open_sheet == bool(extra) and len(shape.profile.points) >= 39


def test_import_finishes_when_its_reader_has_gone(pov_file, tmp_path):
    """``lathe-profile --from-pov f.pov 2>&1 | head -1``: the reader goes
    after one line; the import still writes every object (it stopped at the
    next print with "Broken pipe", 2 of 4 objects written) and exits 0."""
    out = tmp_path / "piped"
    proc = subprocess.Popen([sys.executable, "-m", "lathe_shape.cli.profile", "--from-pov", str(pov_file),
                             "-o", str(out)], stdout=subprocess.PIPE, stderr=subprocess.STDOUT)
    proc.stdout.readline()
    proc.stdout.close()  # the reader has gone
    assert proc.wait(timeout=120) == 0
    assert sorted(p.name for p in out.glob("*.xml")) == sorted(
        f"{name}.xml" for name in ("Vase", "Goblet", "scene_lathe3", "scene_lathe4", "scene_sor1"))
