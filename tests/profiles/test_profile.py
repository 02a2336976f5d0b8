"""Profile parsing, validation, orientation and crease-aware normals."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from conftest import random_ring_profile, random_vase_profile

from lathe_shape.profiles import ProfileError, make_profile, parse_profile_string, read_profile_csv

GLASS = "0 0, 1 0, 1 2, 0.9 2, 0.9 0.1, 0 0.1"


def profile_from(text: str, crease_angle: float = 30.0):
    pts, sharp, labels = parse_profile_string(text)
    return make_profile(pts, sharp, labels, source="parameter 'profile'", crease_angle=crease_angle)


def signed_area(pts: np.ndarray) -> float:
    r, z = pts[:, 0], pts[:, 1]
    return 0.5 * float(np.sum(r * np.roll(z, -1) - np.roll(r, -1) * z))


def test_orientation_is_normalised_to_clockwise():
    a = profile_from(GLASS)
    reversed_text = ", ".join(reversed([p.strip() for p in GLASS.split(",")]))
    b = profile_from(reversed_text)
    for prof in (a, b):
        assert signed_area(prof.points) < 0.0  # clockwise in (r right, z up)
        assert not prof.closed_loop
        assert prof.points[0, 0] == 0.0 and prof.points[-1, 0] == 0.0
    assert a.segment_count == b.segment_count == 5
    # Outward normal of the bottom annulus points down, of the outer wall out.
    normals = a.segment_normals()
    p0, p1 = a.segment_points()
    bottom = np.flatnonzero((p0[:, 1] == 0.0) & (p1[:, 1] == 0.0))[0]
    outer = np.flatnonzero((p0[:, 0] == 1.0) & (p1[:, 0] == 1.0))[0]
    np.testing.assert_allclose(normals[bottom], [0.0, -1.0], atol=1e-15)
    np.testing.assert_allclose(normals[outer], [1.0, 0.0], atol=1e-15)


def test_closed_loop_forms():
    ring = profile_from("1 0, 2 0, 2 1, 1 1, 1 0")
    assert ring.closed_loop and len(ring.points) == 4 and ring.segment_count == 4
    # A loop that runs along the axis becomes an axis-ended chain.
    cyl = profile_from("0 0, 1 0, 1 1, 0 1, 0 0")
    assert not cyl.closed_loop and cyl.segment_count == 3
    assert cyl.points[0, 0] == 0.0 and cyl.points[-1, 0] == 0.0


@pytest.mark.parametrize(
    "text, message",
    [
        ("0 0, 1 1", "a profile needs at least 3 distinct points, got 2"),
        ("0 0, 1 0, 1 1, 1 0.5, 0 2", "point 3: profile intersects itself: it folds back at (1, 1)"),
        ("0 0, nan 1, 0 2", "point 2: non-finite coordinate (nan, 1)"),
        ("0 0, 1 inf, 0 2", "point 2: non-finite coordinate (1, inf)"),
        ("0 0, -0.5 1, 0 2", "point 2: negative radius r = -0.5 (r must be >= 0)"),
        ("0 0, 1 0, 1 0, 1 1, 0 1", "point 3: repeats the previous point (1, 0): zero-length segment"),
        ("0 0, 1 0, 1 1, 0.5 1",
         "profile is not closed: its ends (0, 0) and (0.5, 1) must be the same point, or both must lie "
         "on the axis (r = 0)"),
        ("0 0, 1 0, 1 2, 0.5 1, 1.5 1, 0 2",
         "profile intersects itself: the segment (1.0, 0.0) -> (1.0, 2.0) from point 2 to point 3 meets the "
         "segment (0.5, 1.0) -> (1.5, 1.0) from point 4 to point 5"),
        ("0 0, 1 0, 0 1, 1 1, 0 2",
         "point 3: the profile touches the axis at (0, 1) between its ends: a profile meets the axis (r = 0) "
         "only at its first and last point"),
        ("0 0, 1 1, 2 2, 0 0", "profile encloses no area"),
        ("0 0, 1 x, 0 1", "point 2: 'x' is not a number"),
        ("0 0, 1, 0 1", "point 2: expected 'r z' or 'r z sharp', got '1'"),
    ],
)
def test_bad_input_messages(text, message):
    with pytest.raises(ProfileError) as info:
        profile_from(text)
    assert message in str(info.value)
    assert "parameter 'profile'" in str(info.value)


def test_bad_crease_angle():
    with pytest.raises(ProfileError, match=r"crease_angle must be within \[0, 180\] degrees, got -5"):
        profile_from(GLASS, crease_angle=-5)


def test_csv_reader(tmp_path):
    path = tmp_path / "p.csv"
    path.write_text("# a glass\nr,z,sharp\n0,0,0\n1,0,1  # corner\n\n1,2,0\n0.9,2\n0.9,0.1\n0,0.1\n")
    pts, sharp, labels = read_profile_csv(path)
    assert pts.shape == (6, 2) and sharp.tolist() == [False, True, False, False, False, False]
    assert labels[0].endswith("p.csv, line 3")
    bad = tmp_path / "bad.csv"
    bad.write_text("r,z\n0,0\n-1,1\n0,2\n")
    pts, sharp, labels = read_profile_csv(bad)
    with pytest.raises(ProfileError, match=r"bad\.csv, line 3: negative radius"):
        make_profile(pts, sharp, labels, source=str(bad))
    with pytest.raises(ProfileError, match=r"missing\.csv: cannot read profile file"):
        read_profile_csv(tmp_path / "missing.csv")
    cols = tmp_path / "cols.csv"
    cols.write_text("0,0,0,0\n")
    with pytest.raises(ProfileError, match=r"cols\.csv, line 1: expected 2 or 3 columns"):
        read_profile_csv(cols)


def test_csv_separators(tmp_path):
    """Commas, semicolons or white space, one of them per file: a decimal
    comma among semicolons (``1,5;0``) was read as the point (1, 5) with a
    sharp flag 0, and a stray semicolon among commas passed unnoticed."""
    for name, text in (("commas", "0,0\n1.5,0\n1.2,1\n0,1\n"),
                       ("semicolons", "r;z\n0;0\n1.5;0\n1.2;1\n0;1\n"),
                       ("spaces", "0 0\n1.5  0\n1.2\t1\n0 1\n")):
        path = tmp_path / f"{name}.csv"
        path.write_text(text)
        assert read_profile_csv(path)[0].tolist() == [[0, 0], [1.5, 0], [1.2, 1], [0, 1]], name
    euro = tmp_path / "euro.csv"
    euro.write_text("r;z\n0;0\n1,5;0\n1,2;1\n0;1\n")
    with pytest.raises(ProfileError, match=r"euro\.csv, line 3: a decimal comma \('1,5;0'\); numbers are "
                                           r"written with a point \(1\.5, not 1,5\)"):
        read_profile_csv(euro)
    for number, text in ((2, "0 0\n1,5 0\n1,2 1\n0 1\n"), (1, "1,5 0\n0 0\n1.2 1\n")):
        spaced = tmp_path / "spaced.csv"
        spaced.write_text(text)
        with pytest.raises(ProfileError, match=rf"spaced\.csv, line {number}: a decimal comma \('1,5 0'\)"):
            read_profile_csv(spaced)
    mixed = tmp_path / "mixed.csv"
    mixed.write_text("r,z\n0,0\n1.5,0\n1.2;1\n0,1\n")
    with pytest.raises(ProfileError, match=r"mixed\.csv, line 4: columns separated by semicolons, where "
                                           r"line 2 separates them by commas: use one separator"):
        read_profile_csv(mixed)


def expected_vertex_normals(pts: np.ndarray, closed: bool, crease: float, sharp: np.ndarray):
    """Independent per-vertex (in, out) normals by walking the chain."""
    n = len(pts)
    out = {}
    cos_c = math.cos(math.radians(crease))
    seg_count = n if closed else n - 1

    def seg_normal(k):
        a, b = pts[k], pts[(k + 1) % n]
        v = np.array([a[1] - b[1], b[0] - a[0]])
        return v / math.hypot(*v)

    for v in range(n):
        incoming = (v - 1) % n if (closed or v > 0) else None
        outgoing = v if (closed or v < n - 1) else None
        if incoming is not None and incoming >= seg_count:
            incoming = None
        nin = seg_normal(incoming) if incoming is not None else None
        nout = seg_normal(outgoing) if outgoing is not None else None
        if nin is not None and nout is not None and not sharp[v] and nin @ nout >= cos_c:
            s = nin + nout
            nin = nout = s / np.linalg.norm(s)
        out[v] = (nin, nout)
    return out


@pytest.mark.parametrize("seed", range(6))
def test_normals_match_independent_computation(seed):
    rng = np.random.default_rng(seed)
    raw = random_ring_profile(rng, 12) if seed % 2 == 0 else random_vase_profile(rng, 10)
    sharp = rng.uniform(size=len(raw)) < 0.2
    crease = float(rng.uniform(10.0, 60.0))
    prof = make_profile(raw, sharp, crease_angle=crease)
    pts = prof.points
    expected = expected_vertex_normals(pts, prof.closed_loop, crease, prof.sharp)
    for s, (a, b) in enumerate(prof.segments):
        exp_start = expected[a][1]
        exp_end = expected[b][0]
        if not prof.closed_loop and pts[a, 0] == 0.0 and a == 0:
            # Axis end: axial when the cap is within the crease angle.
            seg = prof.segment_normals()[s]
            if not prof.sharp[a] and abs(seg[1]) >= math.cos(math.radians(crease)):
                exp_start = np.array([0.0, math.copysign(1.0, seg[1])])
        if not prof.closed_loop and pts[b, 0] == 0.0 and b == len(pts) - 1:
            seg = prof.segment_normals()[s]
            if not prof.sharp[b] and abs(seg[1]) >= math.cos(math.radians(crease)):
                exp_end = np.array([0.0, math.copysign(1.0, seg[1])])
        np.testing.assert_allclose(prof.normal_start[s], exp_start, atol=1e-12)
        np.testing.assert_allclose(prof.normal_end[s], exp_end, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(prof.normal_start, axis=1), 1.0, atol=1e-12)


def test_crease_angle_and_sharp_flag():
    # The 90 degree corners of the glass are creases at 30 degrees ...
    prof = profile_from(GLASS, crease_angle=30.0)
    assert not np.allclose(prof.normal_end[:-1], prof.normal_start[1:])
    # ... and averaged at 100 degrees, except where flagged sharp.
    smooth = profile_from(GLASS, crease_angle=100.0)
    np.testing.assert_allclose(smooth.normal_end[:-1], smooth.normal_start[1:])
    flagged = profile_from(GLASS.replace("1 2,", "1 2 1,"), crease_angle=100.0)
    k = int(np.flatnonzero((flagged.points[:, 0] == 1) & (flagged.points[:, 1] == 2))[0])
    seg_in = int(np.flatnonzero(flagged.segments[:, 1] == k)[0])
    assert not np.allclose(flagged.normal_end[seg_in], flagged.normal_start[seg_in + 1])


CUP = [[0, 0], [1, 0], [1, 2], [0.9, 2], [0.9, 0.1], [0, 0.1]]


@pytest.mark.parametrize("kwargs, message", [
    # (4, 3) was read as 6 points of other geometry; (2, N) named points never given
    ({"points": [[0, 0, 1], [0, 1, 1], [0.5, 1.5, 0.2], [2, 0, 2]]}, "got an array of shape (4, 3)"),
    ({"points": np.array(CUP).T}, "got an array of shape (2, 6)"),
    ({"points": CUP, "sharp": [1, 0]}, "'sharp' must hold one flag per point (6), got shape (2,)"),
    ({"points": CUP, "sharp": [0] * 8}, "'sharp' must hold one flag per point (6), got shape (8,)"),
    ({"points": CUP, "labels": ["a"]}, "'labels' must name every point (6), got 1"),
    ({"points": CUP, "crease_angle": "30"}, "crease_angle must be a number of degrees, got '30'"),
    # (products of coordinates underflowed: "repeats the previous point", "encloses no area")
    ({"points": np.array(CUP) * 1e-300}, "too small to check: its largest coordinate is 2e-300"),
])
def test_python_arguments_are_checked(kwargs, message):
    with pytest.raises(ProfileError, match=f"^cup: .*{re.escape(message)}"):
        make_profile(source="cup", **kwargs)
    # The flat r0, z0, r1, z1, ... form (the differentiable parameter's) stays accepted
    assert len(make_profile(np.ravel(CUP)).points) == 6
