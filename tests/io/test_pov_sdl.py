"""The SDL front end of ``lathe-profile --from-pov`` (issue 28) on small
scenes written here: expressions and directives in points and transforms,
transforms composed through objects, matrix and transform { }, CSG notes,
one failing object among good ones, duplicate names, includes (and what is
refused), and the bounds on loops and macro recursion."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from lathe_shape.cli import profile as cli
from lathe_shape.profiles.pov import read_pov_objects
from lathe_shape.profiles.pov_sdl import interpreter

SCENE = """#version 3.7;
#include "colors.inc"
#declare N = 5;
#declare R = 2;
#macro Pt(k) <R*sin(k/(N-1)*pi), -R*cos(k/(N-1)*pi)> #end
camera { location <0, 2, -10> look_at 0 }
light_source { <10, 10, -10> color White }
#declare Ball = lathe {
  cubic_spline N + 2,
  <0, -R - 0.1>,
  #declare k = 0;
  #while (k < N) Pt(k), #declare k = k + 1; #end
  <0, R + 0.1>
  translate -y*0.363 rotate x*90 translate 1
}
object { Ball matrix <1, 0, 0, 0, 1, 0, 0, 0, 1, 1, 2, 3> transform { scale 2 } }
difference {
  sor { 4, <1, -1>*0.5, <1, 0>, <1.2, 1>, <1, 2> }
  box { -1, 1 }
  pigment { rgb <1, 0, 0> }
}
"""


def _rot_x(deg):
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[1, 0, 0, 0], [0, c, -s, 0], [0, s, c, 0], [0, 0, 0, 1.0]])


def _tr(v):
    m = np.eye(4)
    m[:3, 3] = v
    return m


def test_expressions_loops_macros_and_transforms(tmp_path):
    path = tmp_path / "scene.pov"
    path.write_text(SCENE)
    blocks, notes = read_pov_objects(path)
    ball, sor = blocks
    assert (ball.name, ball.kind, sor.name, sor.kind) == ("Ball", "catmull_rom", "scene_sor1", "sor")
    k = np.arange(5)
    expected = np.column_stack([2 * np.sin(k / 4 * np.pi), -2 * np.cos(k / 4 * np.pi)])
    np.testing.assert_allclose(ball.points[1:-1], expected, atol=1e-12)
    np.testing.assert_allclose(ball.points[[0, -1]], [[0, -2.1], [0, 2.1]])
    own = _tr([1, 1, 1]) @ _rot_x(90) @ _tr([0, -0.363, 0])
    placed = np.diag([2.0, 2, 2, 1]) @ _tr([1, 2, 3]) @ own
    np.testing.assert_allclose(ball.transform, placed, atol=1e-12)
    np.testing.assert_allclose(sor.points[0], [0.5, -0.5])
    assert any("difference at" in n and "1 other object not imported" in n for n in sor.notes)
    np.testing.assert_allclose(sor.material.color, [1, 0, 0])


def test_one_bad_object_fails_alone(tmp_path, capsys):
    path = tmp_path / "scene.pov"
    path.write_text("#declare Cup = lathe { 3, <0, 0>, <1, 0>, <0, 1> }\n"
                    "lathe {\n 3, <0, 0>, <Q, 0>, <0, 1> }\n"
                    "#declare Cup = sor { 4, <0, 0>, <1, 0>, <1.2, 1>, <1, 2> }\n"
                    "object { Cup translate 1 }\n")
    out = tmp_path / "out"
    assert cli.main(["--from-pov", str(path), "-o", str(out)]) == 1
    captured = capsys.readouterr()
    lines = captured.out.strip().splitlines()
    assert len(lines) == 3
    assert lines[0].startswith(f"{path}:1: lathe 'Cup': polyline, 3 points")
    assert lines[1] == f"{path}:2: lathe 'scene_lathe2': not imported: {path}:3: unknown identifier 'Q'"
    assert lines[2].startswith(f"{path}:4: sor 'Cup_2': sor, 4 points")
    assert "the name 'Cup' is taken by an earlier object: written as 'Cup_2'" in captured.err
    assert sorted(p.name for p in out.iterdir()) == ["Cup.csv", "Cup.xml", "Cup_2.csv", "Cup_2.xml"]
    assert 'value="1 0 0 1 0 1 0 1 0 0 1 1 0 0 0 1"' in (out / "Cup_2.xml").read_text()


def test_includes(tmp_path):
    (tmp_path / "parts").mkdir()
    (tmp_path / "parts" / "vase.inc").write_text("#declare H = 3;\n"
                                                 "#declare Vase = lathe { 3, <0, 0>, <1, 0>, <0, H> }\n")
    path = tmp_path / "scene.pov"
    path.write_text('#include "parts/vase.inc"\nobject { Vase scale H }\n')
    blocks, _ = read_pov_objects(path)
    assert blocks[0].name == "Vase" and blocks[0].where.endswith("vase.inc:2")
    np.testing.assert_allclose(blocks[0].points[2], [0, 3])
    np.testing.assert_allclose(np.diag(blocks[0].transform), [3, 3, 3, 1])
    (tmp_path / "sub").mkdir()
    inner = tmp_path / "sub" / "scene.pov"
    for name in ("../parts/vase.inc", str(tmp_path / "parts" / "vase.inc")):
        inner.write_text(f'#include "{name}"\nlathe {{ 3, <0, 0>, <1, 0>, <0, 1> }}\n')
        blocks, notes = read_pov_objects(inner)
        assert len(blocks) == 1 and blocks[0].error is None
        assert any(re.search(r"scene\.pov:1: #include .*only files in the scene's folder", n) for n in notes)


@pytest.mark.parametrize("include", ['"colors.inc"\n#include "mine.inc"', '"mine.inc"'])
def test_a_missing_include_loses_nothing_after_it(tmp_path, include):
    """A user's own include that is not there: the statements after it
    were skipped (after an include that was read, the reader stopped and
    the objects came from the dormant reader, unplaced and with their
    generated names; as the first line, the object after it went as the
    failed include's statement)."""
    path = tmp_path / "scene.pov"
    path.write_text(f"#include {include}\n"
                    "#declare Glass = lathe { 4, <0, 0>, <1, 0>, <1, 1>, <0, 1> }\n"
                    "object { Glass translate <5, 0, 0> }\n"
                    "object { lathe { 3, <0, 0>, <2, 0>, <0, 2> } translate <-5, 0, 0> }\n")
    blocks, notes = read_pov_objects(path)
    assert [(b.name, b.transform[0, 3]) for b in blocks] == [("Glass", 5.0), ("scene_lathe2", -5.0)]
    missing = [n for n in notes if "mine.inc" in n]
    assert len(missing) == 1
    assert re.fullmatch(r".*scene\.pov:\d: #include \"mine\.inc\": file not found in .*", missing[0])
    folders = missing[0].split("file not found in ")[1].split(", ")
    assert len(folders) == len(set(folders))  # (each folder once)
    assert not any("not part of the rendered scene" in n for n in notes)


def test_a_bad_statement_fails_alone_after_a_declared_lathe(tmp_path, capsys):
    """A statement that cannot be read after a #declared lathe took the
    lathe down with it, blamed on the other line."""
    path = tmp_path / "scene.pov"
    path.write_text("#declare L = lathe { 4, <0, 0>, <1, 0>, <1, 1>, <0, 1> }\n"
                    "#declare X = 1 +;\n"
                    "object { L translate <5, 0, 0> }\n")
    out = tmp_path / "out"
    assert cli.main(["--from-pov", str(path), "-o", str(out)]) == 0
    captured = capsys.readouterr()
    assert captured.out.startswith(f"{path}:1: lathe 'L': polyline, 4 points")
    assert f"{path}:2: expected a number or vector, got ';'" in captured.err
    assert 'value="1 0 0 5 0 1 0 0 0 0 1 0 0 0 0 1"' in (out / "L.xml").read_text()


def test_bounds(tmp_path, monkeypatch):
    monkeypatch.setattr(interpreter, "MAX_ITERATIONS", 1000)
    path = tmp_path / "scene.pov"
    path.write_text("#declare i = 0;\n#while (1)\n #declare i = i + 1;\n#end\n"
                    "lathe { 3, <0, 0>, <1, 0>, <0, 1> }\n")
    blocks, notes = read_pov_objects(path)
    assert any("more than 1,000 loop iterations" in n for n in notes)
    path.write_text("#macro F(n) F(n + 1) #end\nF(0)\nlathe { 3, <0, 0>, <1, 0>, <0, 1> }\n")
    blocks, notes = read_pov_objects(path)
    assert any("more than 64 nested macro calls" in n for n in notes)
    assert blocks and blocks[0].error is None


@pytest.mark.parametrize("strict", [False, True])
def test_self_crossing_loop(tmp_path, capsys, strict):
    """lathe2.pov's shape1 in short: a repeated control point makes a small
    loop; imported as the rest plus the loop (POV-Ray's surface), or
    refused with --strict-curves."""
    path = tmp_path / "goblet.pov"
    path.write_text("lathe { cubic_spline 8, <0, 0>, <0, 0>, <0.3, 0>, <0.3, 0>, <0.06, 0.08>, "
                    "<0.05, 0.5>, <0, 0.6>, <0, 0.7> }\n")
    out = tmp_path / "out"
    rc = cli.main(["--from-pov", str(path), "-o", str(out)] + (["--strict-curves"] if strict else []))
    captured = capsys.readouterr()
    if strict:
        assert rc == 1 and "not imported" in captured.out and "intersects itself" in captured.out
    else:
        assert rc == 0 and "warning: the curve crosses itself" in captured.err
        assert (out / "goblet_lathe1_loop1.csv").is_file()
        assert 'id="goblet_lathe1_loop1"' in (out / "goblet_lathe1.xml").read_text()


def test_a_missing_include_inside_an_if(tmp_path):
    """Inside an #if, the failed include's recovery dropped the #if: the
    lathe after it was lost and '#else/#end without a matching #if' noted."""
    path = tmp_path / "scene.pov"
    path.write_text('#if (1)\n  #include "mine.inc"\n'
                    "  lathe { 4, <0, 0>, <1, 0>, <1, 1>, <0, 1> translate 3*x }\n"
                    "#else\n  lathe { 4, <0, 0>, <2, 0>, <2, 1>, <0, 1> }\n#end\n")
    blocks, notes = read_pov_objects(path)
    assert [(b.name, b.transform[0, 3]) for b in blocks if b.error is None][0] == ("scene_lathe1", 3.0)
    assert not any("without a matching #if" in n for n in notes)
    assert sum("mine.inc" in n for n in notes) == 1
