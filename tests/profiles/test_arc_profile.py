"""Tests of the section 2.3 arc profile builder (lathe_shape.profiles.arcs):
constant wall thickness, equal division, validity, spec files and errors."""

from __future__ import annotations

import json
import math
import sys

import numpy as np
import pytest

from lathe_shape.profiles import ProfileError, build_from_spec, load_profile_spec, make_profile, read_points
from lathe_shape.profiles.arcs import ArcPiece

#: A goblet: foot, stem, fillet, spherical bowl (centre on the axis), upper arc.
SPEC = {
    "start": [0.0, 0.0], "max_step_deg": 10.0, "thickness": 0.2,
    "base": [
        {"line": {"to": [3.0, 0.0]}},
        {"arc": {"radius": 0.15, "sweep": 180.0, "segments": 4}},
        {"line": {"to": [1.0, 0.3]}},
        {"arc": {"radius": 0.6, "sweep": -90.0}},
        {"line": {"length": 4.0}},
    ],
    "wall": [
        {"arc": {"radius": 0.8, "sweep": -60.0}},
        {"arc": {"radius": 3.0, "sweep": 60.0, "max_step_deg": 7.5}},
        {"arc": {"radius": 12.0, "sweep": 12.0}},
    ],
    "rim": {"type": "round", "segments": 4},
    "bottom": "flat",
}


def _wall_pieces(spec):
    """Outer and inner arc pieces, rebuilt with the builder internals."""
    from lathe_shape.profiles import arcs as A

    b = A.ArcProfileBuilder(spec["start"], 0.0, spec["max_step_deg"])
    for e in spec["base"]:
        A._add_element(b, e, "base")
    n = len(b.pieces)
    for e in spec["wall"]:
        A._add_element(b, e, "wall")
    return b.pieces[n:]


def _dist_to_polyline(p, poly):
    a, b = poly[:-1], poly[1:]
    ab = b - a
    t = np.clip(np.einsum("ij,ij->i", p - a, ab) / np.einsum("ij,ij->i", ab, ab), 0, 1)
    return float(np.min(np.linalg.norm(a + t[:, None] * ab - p, axis=1)))


def test_valid_and_clockwise():
    pts, sharp = build_from_spec(SPEC)
    prof = make_profile(pts, sharp)
    assert prof.segment_count == len(pts) - 1
    # Returned clockwise already (negative shoelace area): make_profile keeps it.
    r, z = pts[:, 0], pts[:, 1]
    assert np.sum(r * np.roll(z, -1) - np.roll(r, -1) * z) < 0
    assert np.array_equal(prof.points, pts)
    assert pts[0, 0] == 0.0 and pts[-1, 0] == 0.0


def test_constant_thickness_and_concentric():
    t = SPEC["thickness"]
    pts, _ = build_from_spec(SPEC)
    outer = _wall_pieces(SPEC)
    inner = [p.offset_left(t) for p in outer]
    steps = []
    for o, i in zip(outer, inner, strict=True):
        assert isinstance(o, ArcPiece) and isinstance(i, ArcPiece)
        assert np.array_equal(o.center, i.center)          # concentric
        assert abs(abs(o.radius - i.radius) - t) < 1e-12   # radius changed by t
        # Same division angles: vertex k of the inner arc on vertex k's radius.
        ov, iv = o.points(), i.points()[::-1]
        ov = np.vstack([o.point(o.a0), ov])[:-1]
        assert np.allclose(np.linalg.norm(ov - iv, axis=1), t, atol=1e-12)
        steps.append(abs(o.a1 - o.a0) / o.n)
    # Every inner vertex of the built profile is t (within the chord error
    # t (1 - cos(step/2))) from the outer polyline and exactly t from the arcs.
    outer_poly = np.vstack([outer[0].point(outer[0].a0)] + [p.points() for p in outer])
    inner_pts = np.vstack([p.points() for p in inner])
    chord_tol = t * (1 - math.cos(max(steps) / 2)) + 1e-9
    for p in inner_pts:
        assert any(np.allclose(p, q) for q in pts)          # it is in the profile
        d_poly = _dist_to_polyline(p, outer_poly)
        assert abs(d_poly - t) <= chord_tol
        d_arc = min(abs(np.linalg.norm(p - o.center) - o.radius) for o in outer
                    if abs(np.linalg.norm(p - o.center) - (o.radius + (-t if o.a1 > o.a0 else t))) < 1e-9)
        assert abs(d_arc - t) < 1e-12


def test_equal_division():
    for piece in _wall_pieces(SPEC):
        p = np.vstack([piece.point(piece.a0), piece.points()])
        seg = np.linalg.norm(np.diff(p, axis=0), axis=1)
        assert np.allclose(seg, seg[0], rtol=1e-12)
        assert math.degrees(abs(piece.a1 - piece.a0)) / piece.n <= 10.0 + 1e-9
    big = _wall_pieces(SPEC)[1]
    assert big.n == math.ceil(60 / 7.5)


def test_round_bottom_and_flat_rim():
    spec = {"start": [0.0, 1.0], "thickness": 0.3, "max_step_deg": 15.0,
            "wall": [{"arc": {"center": [0.0, 5.0], "sweep": 90.0}}, {"line": {"length": 3.0}}],
            "rim": {"type": "flat"}, "bottom": "axis"}
    pts, sharp = build_from_spec(spec)
    prof = make_profile(pts, sharp)
    assert pts[0, 0] == 0.0 and pts[-1, 0] == 0.0
    # Inner sphere reaches the axis at z = 5 - (4 - 0.3).
    assert np.isclose(pts[0, 1], 5.0 - 3.7) or np.isclose(pts[-1, 1], 5.0 - 3.7)
    assert sharp.sum() == 2 and prof.segment_count == len(pts) - 1


def test_json_and_toml_files(tmp_path):
    path = tmp_path / "glass.json"
    path.write_text(json.dumps(SPEC))
    pts, sharp, labels = load_profile_spec(str(path))
    ref, _ = build_from_spec(SPEC)
    assert np.array_equal(pts, ref) and len(labels) == len(pts)
    assert labels[3].startswith(str(path))
    if sys.version_info >= (3, 11):
        toml = tmp_path / "glass.toml"
        toml.write_text('start = [0.0, 1.0]\nthickness = 0.3\nmax_step_deg = 15.0\nrim = "flat"\n'
                        '[[wall]]\narc = { center = [0.0, 5.0], sweep = 90.0 }\n'
                        '[[wall]]\nline = { length = 3.0 }\n')
        pts, _, _ = load_profile_spec(str(toml))
        make_profile(pts)


@pytest.mark.parametrize("patch, key", [
    ({"thickness": -1}, "thickness"),
    ({"colour": 1}, "colour"),
    ({"wall": [{"arc": {"radius": 1.0}}]}, "sweep"),
    ({"wall": [{"arc": {"radius": 1.0, "sweep": 20, "bogus": 1}}]}, "bogus"),
    ({"wall": [{"spline": {}}]}, "wall[0]"),
    ({"wall": [{"line": {"length": 1.0}}, {"arc": {"center": [9.0, 9.0], "sweep": 10}}]}, "wall[1]"),
    ({"rim": {"type": "wavy"}}, "rim.type"),
    ({"bottom": "up"}, "bottom"),
    ({"wall": [{"arc": {"radius": 0.1, "sweep": 30}}]}, "thickness"),
    ({"start": "origin"}, "start"),
    ({"base": [{"line": {"to": [3.0, 0.0], "segments": 0}}]}, "segments"),
    ({"heading_deg": "north"}, ": heading_deg: expected a finite number"),  # (was "heading_deg.heading_deg")
])
def test_spec_errors(tmp_path, patch, key):
    path = tmp_path / "bad.json"
    path.write_text(json.dumps({**SPEC, **patch}))
    with pytest.raises(ProfileError) as info:
        load_profile_spec(str(path))
    msg = str(info.value)
    assert msg.startswith(str(path)) and key in msg, msg


def test_file_errors(tmp_path):
    with pytest.raises(ProfileError, match="cannot read"):
        load_profile_spec(str(tmp_path / "missing.json"))
    bad = tmp_path / "broken.json"
    bad.write_text("{")
    with pytest.raises(ProfileError, match="not a valid JSON"):
        load_profile_spec(str(bad))


def test_paper_specs_load_in_scene():
    """The committed paper scenes load, with the segment counts of the paper."""
    import mitsuba as mi
    from conftest import ROOT

    counts = {"fig8a": 31, "fig8b": 12, "fig9": 42, "fig10a": 58, "fig10b": 86}
    for fig, n in counts.items():
        scene = mi.load_file(str(ROOT / "scenes" / "paper" / f"{fig}.xml"), res="8", spp="1")
        lathe = [s for s in scene.shapes() if hasattr(s, "profile")][0]
        assert lathe.profile.segment_count == n, fig


@pytest.mark.parametrize("name", ["wine_glass", "sundae_cup", "brandy_bottle"])
def test_scene_specs_build_the_scene_profiles(name):
    """scenes/NAME.csv is scenes/NAME.json built by the library (written with
    6 decimals by scripts/make_profiles.py)."""
    from conftest import ROOT

    built, built_sharp, _ = read_points(ROOT / "scenes" / f"{name}.json")
    stored, stored_sharp, _ = read_points(ROOT / "scenes" / f"{name}.csv")
    assert built.shape == stored.shape and np.array_equal(built_sharp, stored_sharp)
    assert np.abs(built - stored).max() <= 5e-7 + 1e-12


def test_readme_spec_example_is_a_valid_profile():
    """The arc-profile spec shown in the README builds a valid closed
    profile (a user copies it)."""
    import re
    from pathlib import Path

    readme = (Path(__file__).resolve().parents[2] / "README.md").read_text(encoding="utf-8")
    blocks = [b for b in re.findall(r"```json\n(.*?)```", readme, re.S) if '"base"' in b]
    assert blocks
    for block in blocks:
        points, sharp = build_from_spec(json.loads(block))
        profile = make_profile(points, sharp, source="README spec")
        assert profile.segment_count > 40
