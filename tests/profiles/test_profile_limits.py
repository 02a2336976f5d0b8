"""Issue 10, profile half: the crossing routine against brute force, its
time and memory on large profiles, scale-relative tolerances, parser
hygiene, size limits and lathe-profile without tracebacks."""

from __future__ import annotations

import json
import os
import re
import time
import tracemalloc

import numpy as np
import pytest
from conftest import random_vase_profile
from hypothesis import given, settings
from hypothesis import strategies as st

from lathe_shape.cli import profile as cli
from lathe_shape.profiles import (
    ProfileError,
    limits,
    load_profile_spec,
    make_bspline_profile,
    make_profile,
    parse_profile_string,
    read_profile_csv,
    sources,
)
from lathe_shape.profiles.bspline import to_polyline
from lathe_shape.profiles.crossings import _touching, first_crossing

# ---------------------------------------------------------------------------
# The crossing routine
# ---------------------------------------------------------------------------


def brute_force_crossing(points: np.ndarray, closed: bool, tol: float):
    chain = np.vstack([points, points[:1]]) if closed else points
    m = len(chain) - 1
    i, j = np.triu_indices(m, k=2)
    keep = ~(closed & (i == 0) & (j == m - 1))
    i, j = i[keep], j[keep]
    hit = _touching(chain[i], chain[i + 1], chain[j], chain[j + 1], tol)
    return (int(i[hit][0]), int(j[hit][0])) if hit.any() else None


grid_points = st.lists(st.tuples(st.integers(0, 6), st.integers(0, 6)), min_size=2, max_size=40)


@settings(max_examples=int(os.environ.get("LATHE_FUZZ_EXAMPLES", "60")), deadline=None, derandomize=True)
@given(points=grid_points, closed=st.booleans(), jitter=st.integers(0, 2**32 - 1))
def test_first_crossing_is_the_lowest_brute_force_pair(points, closed, jitter):
    """Grid points (touching and collinear pairs aplenty), sometimes jittered."""
    pts = np.array(points, dtype=float)
    if jitter % 2:
        pts += np.random.default_rng(jitter).normal(scale=0.3, size=pts.shape)
    assert first_crossing(pts, closed, 1e-9) == brute_force_crossing(pts, closed, 1e-9)


def comb(n: int, angle: float) -> np.ndarray:
    """A closed comb of n/2 long thin teeth at ``angle``: every tooth's axis
    aligned box overlaps every other's."""
    m = n // 2
    along = np.array([np.cos(angle), np.sin(angle)])
    across = np.array([along[1], -along[0]]) / m
    base = 5.0 + np.arange(m)[:, None] * across
    pts = np.empty((2 * m, 2))
    pts[0::2], pts[1::2] = base, base + along + 0.5 * across
    return np.vstack([pts[:-1], [5.0 - along + 0.5 * across * m], pts[:1]])


@pytest.mark.parametrize("name", ["ring", "zigzag vase", "comb 30 deg", "comb 45 deg"])
def test_large_profiles_load_fast_in_little_memory(name):
    """100k points: n log n, not the former n^2 (7.7 GB and 26 s at 10k)."""
    if name == "ring":
        a = np.linspace(0.0, 2.0 * np.pi, 100_000, endpoint=False)
        pts = np.stack([1.5 + 0.5 * np.cos(a), 0.5 * np.sin(a)], axis=1)
        pts = np.vstack([pts, pts[:1]])
    elif name == "zigzag vase":
        pts = random_vase_profile(np.random.default_rng(1), 100_000)
    else:
        pts = comb(100_000, np.radians(float(name.split()[1])))
    tracemalloc.start()
    start = time.perf_counter()
    try:
        make_profile(pts, source=name)
        elapsed = time.perf_counter() - start
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert elapsed < 10.0 and peak < 300e6, (elapsed, peak)


def test_large_bspline_loads_fast():
    a = np.linspace(0.0, 2.0 * np.pi, 2000, endpoint=False)
    controls = np.stack([1.5 + (0.5 + 0.05 * np.sin(7 * a)) * np.cos(a), 0.5 * np.sin(a)], axis=1)
    start = time.perf_counter()
    make_bspline_profile(np.vstack([controls, controls[:1]]), "ring")
    assert time.perf_counter() - start < 5.0


def test_crossing_pair_named():
    """The lowest crossing pair is named, with the points' labels (file and
    line: '1, 0.999984' of a 100,000-point file could not be found) in full
    precision; a profile that reaches the axis between its ends (which met
    the axis segment that closes it) is told so."""
    points, sharp, labels = parse_profile_string("0 0, 1 0, 1 2, 0.5 1, 1.5 1, 0 2")
    with pytest.raises(ProfileError) as info:
        make_profile(points, sharp, labels, source="p")
    assert str(info.value) == ("p: profile intersects itself: the segment (1.0, 0.0) -> (1.0, 2.0) from "
                               "point 2 to point 3 meets the segment (0.5, 1.0) -> (1.5, 1.0) from point 4 "
                               "to point 5")
    points, sharp, labels = parse_profile_string("0 0, 1 0, 0 1, 1 1, 0 2")
    with pytest.raises(ProfileError) as info:
        make_profile(points, sharp, labels, source="p")
    assert str(info.value).startswith("parameter 'profile', point 3: the profile touches the axis at (0, 1) "
                                      "between its ends")


# ---------------------------------------------------------------------------
# Tolerances relative to the profile's size
# ---------------------------------------------------------------------------

POLYLINE_CASES = [
    "0 0, 1 0, 1 2, 0.9 2, 0.9 0.1, 0 0.1",
    "0 0, 1 0, 1 1, 1 0.5, 0 2",
    "0 0, 1 0, 0 1, 1 1, 0 2",
    "0 0, 1 1, 2 2, 0 0",
    "1 0, 2 0, 2 1, 1.5 0, 1 1, 1 0",      # touches itself at a vertex
    "1 0, 2 0, 2 1, 1.5 1e-13, 1 1, 1 0",  # ... within 1e-12 of the size
    "1 0, 2 0, 2 1, 1.5 1e-9, 1 1, 1 0",   # clear of it
]

BSPLINE_CASES = [
    [[0, 0], [1, 0], [1, 1], [0, 2]],
    [[0, 0], [1, 0], [-1, 1], [0, 2]],
    [[0, 0], [1, 0], [0.2, 1], [1, 1.2], [1, 0.3], [0, 2]],
    [[0, 0], [1, 0], [1, 1], [1, 1], [1, 1], [0, 2]],
    [[0, 0], [0, 0], [0, 0], [1, 1], [1, 0], [0, 0]],
    [[1, 0], [2, 0], [2, 1], [1, 1], [1, 0]],
]


def outcome(make, points) -> str:
    try:
        make(points)
    except ProfileError as e:
        return re.sub(r"-?\d+(\.\d*)?(e[-+]?\d+)?", "#", str(e))
    return "ok"


@pytest.mark.parametrize("scale", [1e-6, 1e-3, 1e3, 1e6])
def test_verdicts_do_not_depend_on_scale(scale):
    for text in POLYLINE_CASES:
        pts = parse_profile_string(text)[0]
        assert outcome(make_profile, pts * scale) == outcome(make_profile, pts), text
    for controls in BSPLINE_CASES:
        pts = np.array(controls, float)
        assert (outcome(lambda p: make_bspline_profile(p, "s"), pts * scale)
                == outcome(lambda p: make_bspline_profile(p, "s"), pts)), controls


def test_tiny_profile_accepted_and_bow_tie_named():
    make_profile(parse_profile_string("0 0, 1e-6 0, 1e-6 1e-6, 0 1e-6")[0])
    with pytest.raises(ProfileError, match="profile intersects itself"):
        make_profile(parse_profile_string("0 0, 1 1, 1 0, 0 1, 0 0")[0])  # zero net area


# ---------------------------------------------------------------------------
# Parsers
# ---------------------------------------------------------------------------


def test_csv_encoding_and_numbers(tmp_path):
    bom = tmp_path / "bom.csv"
    bom.write_bytes(b"\xef\xbb\xbfr,z\r\n0,0\r\n1,0\r\n1,1\r0,1\n")
    pts, _, labels = read_profile_csv(bom)
    assert pts.tolist() == [[0, 0], [1, 0], [1, 1], [0, 1]] and labels[3].endswith("bom.csv, line 5")
    latin = tmp_path / "latin.csv"
    latin.write_bytes(b"r,z\n0,0\n1,\xff1\n")
    with pytest.raises(ProfileError, match=r"latin\.csv, line 3: not UTF-8 text \(byte 0xff at column 3\)"):
        read_profile_csv(latin)
    for text in ("1_0", "\u0661", "0x10", "1e", "--1"):
        bad = tmp_path / "bad.csv"
        bad.write_text(f"0,0\n{text},1\n", encoding="utf-8")
        with pytest.raises(ProfileError, match=rf"bad\.csv, line 2: '{text}' is not a number"):
            read_profile_csv(bad)
    words = tmp_path / "words.csv"
    words.write_text("0,0\nInf,1\n0,2\n")
    with pytest.raises(ProfileError, match=r"words\.csv, line 2: non-finite coordinate"):
        make_profile(*read_profile_csv(words), source="words.csv")


def test_spec_encoding_and_numbers(tmp_path):
    spec = {"start": [0.0, 0.0], "base": [{"line": {"to": [1.0, 0.0]}}, {"line": {"to": [1.0, 1.0]}},
                                          {"line": {"to": [0.0, 1.0]}}]}
    path = tmp_path / "bom.json"
    path.write_bytes(b"\xef\xbb\xbf" + json.dumps(spec).encode())
    assert len(load_profile_spec(path)[0]) == 4
    path.write_bytes(json.dumps(spec).encode().replace(b"base", b"b\xe9se"))
    with pytest.raises(ProfileError, match=r"bom\.json, line 1: not UTF-8 text \(byte 0xe9 at column"):
        load_profile_spec(path)
    for start, message in (("[1e999, 0]", "expected a finite number"),
                           ("[1" + "0" * 40 + ", 0]", "must be below"),
                           ("[" * 100000, "not a valid JSON file")):
        path.write_text(json.dumps(spec).replace("[0.0, 0.0]", start, 1))
        with pytest.raises(ProfileError, match=message):
            load_profile_spec(path)
    spec["base"][0]["line"]["segments"] = 10**9
    path.write_text(json.dumps(spec))
    with pytest.raises(ProfileError, match="'segments' must be a positive integer, at most 10,000,000"):
        load_profile_spec(path)


# ---------------------------------------------------------------------------
# Size limits
# ---------------------------------------------------------------------------


def test_point_limits(tmp_path, monkeypatch):
    monkeypatch.setattr(limits, "MAX_PROFILE_POINTS", 144)
    monkeypatch.setattr(sources, "MAX_PROFILE_POINTS", 144)
    with pytest.raises(ProfileError, match=r"big: 145 points is too many: validating them would take "
                                           r"about 0\.0 GB; at most 144 points are supported"):
        make_profile(np.zeros((145, 2)), source="big")
    with pytest.raises(ProfileError, match=r"big: 4 control points \(192 curve samples\) is too many.*"
                                           r"at most 3 control points"):
        make_bspline_profile(np.zeros((4, 2)), "big")
    path = tmp_path / "long.csv"
    path.write_text("0,0\n" * 200)
    with pytest.raises(ProfileError, match=r"long\.csv, line 145: at least 145 points is too many"):
        read_profile_csv(path)
    spline = make_bspline_profile(np.array([[0, 0], [1, 1], [0, 2]], float), "s")
    with pytest.raises(ProfileError, match="to_polyline: 145 points is too many"):
        to_polyline(spline.segment_controls, 145)


def test_coordinates_too_large():
    with pytest.raises(ProfileError, match=r"p, point 2: coordinate too large \(1e\+308, 0\)"):
        make_profile(np.array([[0, 0], [1e308, 0], [1, 1], [0, 1]]), source="p")
    with pytest.raises(ProfileError, match="control point 2 is too large"):
        make_bspline_profile(np.array([[0, 0], [1e20, 0], [1, 1], [0, 1]]), "p")


# ---------------------------------------------------------------------------
# lathe-profile
# ---------------------------------------------------------------------------


def run_cli(argv, capsys):
    code = cli.main([str(a) for a in argv])
    out = capsys.readouterr()
    assert "Traceback" not in out.err
    return code, out


def test_cli_refuses_without_traceback(tmp_path, capsys, monkeypatch):
    huge = tmp_path / "huge.csv"
    huge.write_text("r,z\n0,0\n1e308,0\n1,1\n0,1\n")
    code, out = run_cli([huge], capsys)
    assert code == 2 and "huge.csv, line 3: coordinate too large" in out.err
    spline = tmp_path / "s.csv"
    spline.write_text("0,0\n1,0\n1,1\n0,2\n")
    code, out = run_cli([spline, "--kind", "bspline", "--to-polyline", 1_000_001], capsys)
    assert code == 2 and "--to-polyline must be at most 1,000,000 points" in out.err
    for error in (MemoryError(), OverflowError("math range error")):
        def fail(*args, error=error):
            raise error
        monkeypatch.setattr("lathe_shape.profiles.make_bspline_profile", fail)
        code, out = run_cli([spline, "--kind", "bspline"], capsys)
        assert code == 2 and out.err.startswith(f"lathe-profile: error: {spline}: ")
        assert ("out of memory" if isinstance(error, MemoryError) else "OverflowError") in out.err


def test_cli_converts(tmp_path, capsys):
    spline = tmp_path / "s.csv"
    spline.write_text("0,0\n1,0\n1,1\n0,2\n")
    code, out = run_cli([spline, "--kind", "bspline", "--to-polyline", 20000, "-o", tmp_path / "out"], capsys)
    assert code == 0 and (tmp_path / "out" / "s_20000.csv").exists()


def test_toml_spec_with_bom(tmp_path):
    path = tmp_path / "glass.toml"
    path.write_bytes(b"\xef\xbb\xbfstart = [0.0, 0.0]\n[[base]]\nline = { to = [1.0, 0.0] }\n"
                     b"[[base]]\nline = { to = [1.0, 1.0] }\n[[base]]\nline = { to = [0.0, 1.0] }\n")
    assert len(load_profile_spec(path)[0]) == 4
    path.write_bytes(b"start = [0.0, 0.0]\n# caf\xe9\n")
    with pytest.raises(ProfileError, match=r"glass\.toml, line 2: not UTF-8 text \(byte 0xe9 at column 6\)"):
        load_profile_spec(path)


def _scaled_spec(value, scale):
    """An arc spec with every length multiplied by ``scale``."""
    if isinstance(value, dict):
        return {key: (_scaled_spec(v, scale) if key not in ("start", "to", "center", "length", "radius",
                                                            "thickness") else np.multiply(v, scale).tolist())
                for key, v in value.items()}
    if isinstance(value, list):
        return [_scaled_spec(v, scale) for v in value]
    return value


@pytest.mark.parametrize("scale", [1e-6, 1e6])
def test_arc_specs_scale(scale):
    from test_arc_profile import SPEC

    from lathe_shape.profiles import build_from_spec

    reference, sharp = build_from_spec(SPEC)
    scaled, scaled_sharp = build_from_spec(_scaled_spec(SPEC, scale))
    np.testing.assert_allclose(scaled, reference * scale, rtol=1e-9, atol=1e-12 * scale)
    assert np.array_equal(sharp, scaled_sharp)
    make_profile(scaled, scaled_sharp)
