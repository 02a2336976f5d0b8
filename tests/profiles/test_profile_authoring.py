"""Profiles as users write them: header rows, declarations with comments,
arc-spec errors counted along the walk, B-spline sharp flags refused by
the checker as by the shape, fine uniform samplings of open B-splines."""

from __future__ import annotations

import json
import re

import mitsuba as mi
import pytest
from conftest import ROOT

from lathe_shape.cli import profile as cli
from lathe_shape.profiles import ProfileError, make_profile, read_points, read_profile_options


@pytest.mark.parametrize("header", ["r,z", "x,y", '"r","z"', "radius height", "r;z;sharp"])
def test_any_header_row_names_the_columns(tmp_path, header):
    """Only r,z[,sharp] was a header; x,y or a quoted "r","z" (as
    spreadsheets write) was 'x' is not a number."""
    path = tmp_path / "p.csv"
    path.write_text(f"{header}\n0,0\n1,0\n1,1\n0,1\n")
    points, _, labels = read_points(path)
    assert len(points) == 4 and labels[0] == f"{path}, line 2"
    path.write_text("0,0\nx,y\n1,1\n0,1\n")  # (not the first row: an error)
    with pytest.raises(ProfileError, match=r"line 2: 'x' is not a number"):
        read_points(path)


def test_declarations_take_comments_and_come_once(tmp_path):
    """'# kind: bspline # the paper' was read as no declaration at all (a
    polyline); a second, conflicting '# kind:' silently won."""
    path = tmp_path / "p.csv"
    path.write_text("# kind: bspline   # the paper's glass\n# open: false # solid\n0,0\n1,0\n1,1\n0,1\n")
    assert read_profile_options(path) == {"kind": "bspline", "open": False}
    path.write_text("# kind: bspline\n# kind: polyline\n0,0\n1,0\n1,1\n0,1\n")
    with pytest.raises(ProfileError, match=r"p\.csv, line 2: a second '# kind:' declaration \(the first is "
                                           r"on line 1\): give it once"):
        read_profile_options(path)


def test_arc_spec_errors_count_points_along_the_walk(tmp_path):
    """The spec's points are stored clockwise, its walk reversed: errors
    counted them from the walk's end ('point 5' for the walk's third) and
    called its start its last point."""
    walk = [[1, 0], [-1, 1], [1, 2], [1, 3], [1, 4], [0, 5]]
    path = tmp_path / "negative.json"
    path.write_text(json.dumps({"start": [0, 0], "base": [{"line": {"to": p}} for p in walk]}))
    with pytest.raises(ProfileError, match=r"negative\.json, point 3: negative radius r = -1"):
        make_profile(*read_points(path))
    path = tmp_path / "open.json"
    path.write_text(json.dumps({"start": [0, 0], "base": [{"line": {"to": p}} for p in
                                                          ([1, 0], [1, 2], [0.5, 2])]}))
    with pytest.raises(ProfileError, match=r"open\.json: profile is not closed: its ends \(0\.5, 2\) and "
                                           r"\(0, 0\) must be the same point"):
        make_profile(*read_points(path), source=str(path))


def test_the_checker_refuses_bspline_sharp_flags_as_the_shape_does(tmp_path, capsys):
    path = tmp_path / "sharp.csv"
    path.write_text("# kind: bspline\n0,0\n1,0\n1,2,1\n0,2\n")
    message = f"{path}, line 4: sharp flags are not supported for kind 'bspline' (the curve is smooth)"
    assert cli.main([str(path)]) == 2
    assert message in capsys.readouterr().err
    with pytest.raises(Exception, match=message.replace("(", r"\(").replace(")", r"\)")):
        mi.load_dict({"type": "lathe", "filename": str(path)})


def test_fine_uniform_sampling_of_an_open_bspline(tmp_path, capsys):
    """The tripled end control points stop the curve there (zero speed): a
    uniform sampling of 100,000 points put points 1e-13 apart, and the
    polyline refused that segment as too short."""
    out = tmp_path / "out"
    source = ROOT / "scenes" / "paper" / "glass_bspline.csv"
    assert cli.main([str(source), "--kind", "bspline", "--to-polyline", "100000", "--method", "uniform",
                     "-o", str(out)]) == 0
    written = out / "glass_bspline_100000.csv"
    points, sharp, labels = read_points(written)
    profile = make_profile(points, sharp, labels)  # a valid polyline
    assert 99_000 < len(points) <= 100_000 and profile.points[:, 0].min() == 0.0
    capsys.readouterr()


@pytest.mark.parametrize("kind", ["bspline", "bezier", "catmull_rom"])
def test_curve_kind_errors_name_the_line(tmp_path, kind):
    """'B-spline control point 2 is not finite' made the user count control
    points; the line is named, as for polylines."""
    path = tmp_path / "nan.csv"
    path.write_text(f"# kind: {kind}\n0,0\n1,nan\n1,2\n0,2\n")
    message = f"{path}, line 3: non-finite coordinate (1, nan)"
    assert cli.main([str(path)]) == 2
    with pytest.raises(Exception, match=re.escape(message)):
        mi.load_dict({"type": "lathe", "filename": str(path)})


def test_summaries_describe_the_curve(tmp_path, capsys):
    """A closed loop's last joint was left out of its creases (a square
    torus read 3); a B-spline's r <= was its control polygon's (5.7 for
    the paper's glass, whose curve reaches 4.79)."""
    path = tmp_path / "torus.csv"
    path.write_text("1,0\n2,0\n2,2\n1,2\n1,0\n")
    assert cli.main([str(path)]) == 0
    assert capsys.readouterr().out.rstrip().endswith("closed loop, r <= 2, z in [0, 2], 4 creases at 30 deg")
    assert cli.main([str(ROOT / "scenes" / "paper" / "glass_bspline.csv"), "--kind", "bspline"]) == 0
    assert "r <= 4.78966, z in [0, 17.1638]" in capsys.readouterr().out


def test_no_open_overrides_the_files_open_line(tmp_path, capsys):
    """--open could only switch an open sheet on: a file declaring
    '# open: true' could not be checked as a solid."""
    path = tmp_path / "sheet.csv"
    path.write_text("# open: true\n0,0\n1,0\n1,1\n0,1\n")
    assert cli.main([str(path)]) == 0 and "open sheet" in capsys.readouterr().out
    assert cli.main([str(path), "--no-open"]) == 0 and "both ends on the axis" in capsys.readouterr().out


def test_sor_summary(capsys):
    """The curve's extent of a B-spline (its control polygon's was shown)
    is no sor's: its summary failed with an AttributeError."""
    assert cli.main([str(ROOT / "scenes" / "pov_samples" / "profiles" / "Bottle.csv")]) == 0
    assert "valid sor profile, 8 control points, 7 curve segments, solid, ends on the axis, r <= 2.11823, " \
        "z in [0, 10]" in capsys.readouterr().out


def test_a_closed_profile_read_as_an_open_sheet(tmp_path):
    """'open' on a closed loop said the profile intersects itself, naming
    the two segments that meet at the closing point."""
    with pytest.raises(Exception, match=re.escape(
            "point 5: the profile is closed (its last point repeats the first, (1, 0)), but it is read as "
            "an open sheet ('open' true)")):
        mi.load_dict({"type": "lathe", "profile": "1 0, 2 0, 2 1, 1 1, 1 0", "open": True})
