"""Property-based tests of profile validation (Hypothesis): valid profiles
are accepted at any scale and z offset, invalid ones are refused with a
ProfileError naming the input -- never another exception -- and scaling a
profile by 1e-6 .. 1e6 never changes the verdict.

A few examples per test by default; ``LATHE_FUZZ_EXAMPLES=2000`` for a
longer run."""

from __future__ import annotations

import os
import re

import numpy as np
import pytest
from conftest import random_vase_profile
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from lathe_shape.profiles import ProfileError, make_bspline_profile, make_profile

FUZZ = settings(max_examples=int(os.environ.get("LATHE_FUZZ_EXAMPLES", "25")), deadline=None,
                suppress_health_check=[HealthCheck.too_slow], derandomize=True)

SOURCE = "fuzz.csv"
seeds = st.integers(0, 2**32 - 1)
#: 10^k for k in [-6, 6]: the scales a profile must validate alike at.
scales = st.floats(-6.0, 6.0).map(lambda k: 10.0**k)


def star_ring(rng: np.random.Generator, n: int) -> np.ndarray:
    """A closed loop around a point off the axis (last point == first), its
    vertices in angular order with every angular gap below 180 degrees: a
    star-shaped, hence simple, polygon. (conftest's random_ring_profile may
    leave a larger gap, and then a few points can make a self-crossing loop.)"""
    angles = 2.0 * np.pi * (np.arange(n) + rng.uniform(0.0, 0.9, n)) / n
    radius = rng.uniform(0.4, 1.0, n)
    center = np.array([1.5, rng.uniform(-1.0, 1.0)])
    pts = center + radius[:, None] * np.stack([np.cos(angles), np.sin(angles)], axis=1)
    return np.vstack([pts, pts[:1]])


def valid_raw(seed: int, n: int, ring: bool) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return star_ring(rng, n) if ring else random_vase_profile(rng, n)


def verdict(make, points: np.ndarray) -> str:
    """'ok', or the error message with its numbers blanked out (coordinates
    scale with the profile, the kind of error must not). Any exception other
    than a ProfileError fails the test."""
    try:
        make(points)
    except ProfileError as e:
        message = str(e)
        assert message.startswith(SOURCE), message
        return re.sub(r"-?\d+(\.\d*)?(e[-+]?\d+)?", "#", message)
    return "ok"


def polyline(points: np.ndarray):
    return make_profile(points, source=SOURCE)


def bspline(points: np.ndarray):
    return make_bspline_profile(points, SOURCE)


@FUZZ
@given(seed=seeds, n=st.integers(3, 40), ring=st.booleans(), scale=scales, shift=st.floats(-10.0, 10.0))
def test_valid_profiles_accepted_at_any_scale_and_z_offset(seed, n, ring, scale, shift):
    raw = valid_raw(seed, n, ring)
    moved = raw * scale + np.array([0.0, shift * scale])
    reference, prof = make_profile(raw), make_profile(moved, source=SOURCE)
    assert prof.closed_loop == reference.closed_loop
    assert np.array_equal(prof.segments, reference.segments)
    np.testing.assert_allclose(prof.normal_start, reference.normal_start, atol=1e-9)
    np.testing.assert_allclose(prof.normal_end, reference.normal_end, atol=1e-9)


@FUZZ
@given(seed=seeds, n=st.integers(4, 30), scale=scales)
def test_valid_bsplines_accepted_at_any_scale(seed, n, scale):
    controls = valid_raw(seed, n, ring=True)  # a star-shaped closed control polygon
    assert verdict(bspline, controls * scale) == verdict(bspline, controls)


def _mutate(raw: np.ndarray, kind: str, rng: np.random.Generator) -> tuple[np.ndarray, str]:
    """An invalid profile made from a valid one, and the expected message."""
    pts = raw.copy()
    k = int(rng.integers(1, len(pts) - 1))
    if kind == "negative":
        pts[k, 0] = -rng.uniform(0.01, 1.0)
        return pts, "negative radius"
    if kind == "nan":
        pts[k, int(rng.integers(2))] = [np.nan, np.inf, -np.inf][int(rng.integers(3))]
        return pts, "non-finite coordinate"
    if kind == "huge":
        pts[k, 1] = 1e300
        return pts, "coordinate too large"
    if kind == "few":
        return pts[: int(rng.integers(0, 3))], "at least 3 distinct points"
    if kind == "open":
        return pts[:-1] + np.array([0.5, 0.0]), "profile is not closed"
    if kind == "repeat":
        return np.insert(pts, k, pts[k], axis=0), "repeats the previous point"
    if kind == "collinear":
        t = np.sort(rng.uniform(0.0, 1.0, len(pts)))
        line = np.stack([0.5 + t, 2.0 * t], axis=1)
        return np.vstack([line, line[:1]]), "encloses no area"
    # A bow-tie: the vertices of a convex quadrilateral in the order 0, 2, 1,
    # 3, so that two of its edges are the crossing diagonals.
    angles = np.sort(rng.uniform(0.0, 2.0 * np.pi, 4))
    quad = np.array([2.0, 0.0]) + np.stack([np.cos(angles), rng.uniform(0.5, 2) * np.sin(angles)], 1)
    tie = quad[[0, 2, 1, 3]]
    return np.vstack([tie, tie[:1]]), "profile intersects itself"


@FUZZ
@given(seed=seeds, n=st.integers(4, 30), ring=st.booleans(), scale=scales,
       kind=st.sampled_from(["negative", "nan", "huge", "few", "open", "repeat", "collinear", "bowtie"]))
def test_invalid_profiles_refused_naming_the_input(seed, n, ring, scale, kind):
    rng = np.random.default_rng(seed)
    if kind == "open" and not ring:
        ring = True  # a vase with its ends moved off the axis would still be closed by them
    points, expected = _mutate(valid_raw(seed, n, ring), kind, rng)
    if kind != "huge":
        points = points * scale
    with pytest.raises(ProfileError) as info:
        make_profile(points, source=SOURCE)
    assert str(info.value).startswith(SOURCE) and expected in str(info.value), str(info.value)


coordinates = st.one_of(st.integers(0, 8).map(lambda v: v / 2.0),
                        st.floats(0.0, 10.0).map(lambda v: round(v, 3)))
point_lists = st.lists(st.tuples(coordinates, coordinates), min_size=0, max_size=9)


@FUZZ
@given(points=point_lists, close=st.booleans(), scale=scales)
def test_arbitrary_polylines_same_verdict_at_any_scale(points, close, scale):
    pts = np.array(points + points[:1] if close else points, dtype=float).reshape(-1, 2)
    assert verdict(polyline, pts * scale) == verdict(polyline, pts)


@FUZZ
@given(points=point_lists, close=st.booleans(), scale=scales)
def test_arbitrary_bsplines_same_verdict_at_any_scale(points, close, scale):
    pts = np.array(points + points[:1] if close else points, dtype=float).reshape(-1, 2)
    assert verdict(bspline, pts * scale) == verdict(bspline, pts)


any_float = st.floats(allow_nan=True, allow_infinity=True)


@FUZZ
@given(points=st.lists(st.tuples(any_float, any_float), max_size=8), close=st.booleans())
def test_any_numbers_give_a_profile_or_a_profile_error(points, close):
    pts = np.array(points + points[:1] if close else points, dtype=float).reshape(-1, 2)
    verdict(polyline, pts)
    verdict(bspline, pts)


# -- the CSV reader's fast path -------------------------------------------------

#: Pieces of CSV lines: numbers in several spellings, separators, flags,
#: comments, headers and a few things that are no number.
_CSV_TOKENS = st.sampled_from(["1", "-0.5", "2.", ".25", "1e-3", "+3E2", "inf", "NaN", "1_0", "x", "0",
                               "1", ",", ";", " ", "\t", ", ", " ,", "#c", "# kind: sor", "r", "z",
                               "sharp", "\u00a0", ",,", "٣"])
_CSV_LINES = st.lists(st.lists(_CSV_TOKENS, min_size=0, max_size=6).map("".join), min_size=1, max_size=8)
_COORDINATES = st.floats(-1e3, 1e3, allow_nan=False)
_SEPARATORS = st.sampled_from([",", ";", " ", ", ", "\t"])
_WELL_FORMED = st.lists(st.tuples(_COORDINATES, _COORDINATES, st.sampled_from(["", "0", "1"]),
                                  st.sampled_from(["", "  # note"])), min_size=1, max_size=8)


def _read_both(tmp_path, text: str):
    """The fast reader's and the line-by-line reader's results (or the
    line-by-line reader's error message) for the file ``text``."""
    from lathe_shape.profiles import sources

    path = tmp_path / "fuzz.csv"
    path.write_bytes(text.encode("utf-8"))
    fast = sources._read_csv_rows(path.read_bytes(), str(path))
    try:
        slow = sources._read_csv_lines(str(path))
    except ProfileError as e:
        slow = str(e)
    return fast, slow


@FUZZ
@given(lines=_CSV_LINES, end=st.sampled_from(["\n", "\r\n", "\r"]))
def test_fast_csv_reader_agrees_with_line_reader(tmp_path_factory, lines, end):
    """On any text the fast path of read_profile_csv either gives exactly
    what the line-by-line reader gives (points, sharp flags, line numbers),
    or steps aside for it (None), never accepting what that refuses."""
    fast, slow = _read_both(tmp_path_factory.mktemp("csv"), end.join(lines))
    if fast is None:
        return
    assert not isinstance(slow, str), slow
    np.testing.assert_array_equal(fast[0], slow[0])
    np.testing.assert_array_equal(fast[1], slow[1])
    np.testing.assert_array_equal(fast[2].numbers, slow[2].numbers)


@FUZZ
@given(rows=_WELL_FORMED, header=st.sampled_from(["", "r,z\n", "R Z SHARP\n", "# comment\n"]),
       separator=_SEPARATORS)
def test_fast_csv_reader_reads_well_formed_files(tmp_path_factory, rows, header, separator):
    """Well-formed files (any separator, the same on every line; flags,
    comments, a header) are read by the fast path, with the line reader's
    result."""
    text = header + "".join(f"{r!r}{separator}{z!r}{separator + flag if flag else ''}{note}\n"
                            for r, z, flag, note in rows)
    fast, slow = _read_both(tmp_path_factory.mktemp("csv"), text)
    assert fast is not None, text
    np.testing.assert_array_equal(fast[0], slow[0])
    np.testing.assert_array_equal(fast[1], slow[1])
