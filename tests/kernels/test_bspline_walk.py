"""Watertightness of the B-spline kernel (lathe_shape.kernels.bspline): every
line through a closed cubic lathe crosses it an even number of times
(``count_crossings_bspline``), and ``next_crossing_bspline`` walks a ray
through those crossings without offsets, each one once."""

from __future__ import annotations

import numpy as np
import pytest

mi = pytest.importorskip("mitsuba")
dr = pytest.importorskip("drjit")

from conftest import CUDA_ROUNDING, ROOT  # noqa: E402

from lathe_shape.kernels import bspline as K  # noqa: E402
from lathe_shape.kernels.top_level import ProfileTable  # noqa: E402
from lathe_shape.surfaces import make_surface  # noqa: E402
from lathe_shape.validation import bspline_leaks as L  # noqa: E402
from lathe_shape.validation import leaks  # noqa: E402
from lathe_shape.validation.leaks import parity_rays  # noqa: E402

#: Closed profiles of the other cubic kinds (a sor from the axis to the axis,
#: a Bezier glass with corners where its control points repeat).
OTHER_KINDS = [
    ("sor", "0 -0.5, 1.0 0, 1.2 0.5, 0.6 1.5, 0.4 2.5, 0.5 3, 0 3.5"),
    ("bezier", "0 0, 1.5 0, 1.6 0.3, 1.6 1.2, 1.6 1.2, 1.6 2.2, 0.4 2.4, 0.5 3.2, 0.5 3.2, "
               "0.6 3.6, 0.3 4, 0 4"),
]


def _surface_data(kind: str, text: str):
    points = np.array([[float(v) for v in item.split()] for item in text.split(",")])
    labels = [f"point {k}" for k in range(len(points))]
    return make_surface(kind, points, np.zeros(len(points), bool), labels, "test").data


def _data(name: str):
    if name in ("ring", "egg", "glass12"):
        return L.curve_data(name)
    return _surface_data(name, dict(OTHER_KINDS)[name])


def _rays(data, n: int, seed: int):
    """Rays from outside, a quarter of them aimed exactly at leaf joints and
    a quarter just next to them (parity_rays)."""
    joints = L.leaf_joints(data)
    return parity_rays(joints[:-1], joints[1:], np.random.default_rng(seed), n)


def _jit(o, d):
    return mi.Point3f(o.T.astype(np.float32)), mi.Vector3f(d.T.astype(np.float32))


@pytest.mark.parametrize("name", ["ring", "egg", "glass12", "sor", "bezier"])
def test_every_line_crosses_an_even_number_of_times(name):
    data = _data(name)
    o, d = _rays(data, 40000, 1)
    count = K.count_crossings_bspline(data, *_jit(o, d), mi.Bool(True)).numpy()
    walked, stuck = L.crossing_walk_bspline(data, o, d)
    assert np.mean(count > 0) > 0.8
    assert not np.any(count % 2), np.nonzero(count % 2)[0][:10]
    # The walk finds exactly the crossings that the count counts.
    assert np.array_equal(walked, count)
    assert not stuck.any()


def test_first_crossing_is_the_nearest_hit():
    data = L.curve_data("glass12")
    o, d = _rays(data, 20000, 2)
    o32, d32 = _jit(o, d)
    tmax = dr.full(mi.Float, np.inf, len(o))
    nearest = K.intersect_bspline(data, o32, d32, tmax, mi.Bool(True))
    first, _, _ = K.next_crossing_bspline(data, o32, d32, tmax, mi.Bool(True))
    valid = nearest.valid.numpy()
    assert np.array_equal(first.valid.numpy(), valid)
    t_first, t_nearest = first.t.numpy()[valid], nearest.t.numpy()[valid]
    same = ((first.seg.numpy()[valid] == nearest.seg.numpy()[valid])
            & (first.u.numpy()[valid] == nearest.u.numpy()[valid]) & (t_first == t_nearest))
    # Two crossings at the same s (a ray grazing a joint) are taken in key
    # order by the walk and in traversal order by the nearest hit: the same
    # point, polished on either leaf.
    assert np.mean(same) > 0.999
    assert np.allclose(t_first, t_nearest, rtol=1e-6, atol=0)


def _walk(data, o32, d32, steps: int):
    """The (t, s, key) of the first ``steps`` crossings of every ray (nan
    past the last)."""
    n = dr.width(o32)
    tmax = dr.full(mi.Float, np.inf, n)
    out = np.full((3, steps, n), np.nan)
    s = key = None
    for k in range(steps):
        hit, s, key = K.next_crossing_bspline(data, o32, d32, tmax, mi.Bool(True), s, key)
        valid = hit.valid.numpy()
        out[:, k, valid] = [hit.t.numpy()[valid], s.numpy()[valid], key.numpy()[valid]]
    return out


def test_walk_is_ordered_and_matches_queries_past_each_hit():
    data = L.curve_data("ring")
    o, d = _rays(data, 4000, 3)
    o32, d32 = _jit(o, d)
    t, s, key = _walk(data, o32, d32, 8)
    found = np.isfinite(t)
    # Crossings come in (s, key) order, each key once per ray.
    later = (s[1:] > s[:-1]) | ((s[1:] == s[:-1]) & (key[1:] > key[:-1]))
    assert np.all(later | ~found[1:])
    assert np.all(found[:-1] | ~found[1:])
    # Asking for the first crossing past a t between two of them (after_t,
    # a crossing of another shape) gives the second.
    tmax = dr.full(mi.Float, np.inf, len(o))
    for k in range(3):
        apart = found[k] & found[k + 1] & (t[k + 1] - t[k] > 1e-3)
        after_t = mi.Float(np.where(apart, 0.5 * (t[k] + t[k + 1]), 0).astype(np.float32))
        hit, _, _ = K.next_crossing_bspline(data, o32, d32, tmax, mi.Bool(True), after_t=after_t)
        assert np.array_equal(hit.t.numpy()[apart], t[k + 1][apart].astype(np.float32))
        # Mixed: odd rays by after_t, even ones by the walk's (s, key)
        by_t = apart & (np.arange(len(o)) % 2 == 1)
        after_s = mi.Float(np.where(found[k], s[k], -np.inf).astype(np.float32))
        after_key = mi.UInt32(np.where(by_t | ~found[k], 0xFFFFFFFF, np.nan_to_num(key[k])).astype(np.uint32))
        hit, _, _ = K.next_crossing_bspline(data, o32, d32, tmax, mi.Bool(True), after_s, after_key, after_t)
        both = found[k + 1] & (by_t | (np.arange(len(o)) % 2 == 0))
        assert np.array_equal(hit.t.numpy()[both], t[k + 1][both].astype(np.float32))


@dr.syntax
def _count_in_loop(data, o, d):
    count = mi.UInt32(0)        # crossings found so far
    active = mi.Bool(True)      # the ray still finds crossings
    s = mi.Float(-np.inf)       # the last crossing's place ...
    key = mi.UInt32(0xFFFFFFFF)  # ... and key
    while active:
        hit, s2, key2 = K.next_crossing_bspline(data, o, d, mi.Float(np.inf), active, s, key)
        active &= hit.valid
        count = dr.select(active, count + 1, count)
        s = dr.select(active, s2, s)
        key = dr.select(active, key2, key)
    return count


def test_walk_traces_in_an_outer_symbolic_loop():
    data = L.curve_data("egg")
    o, d = _rays(data, 2000, 4)
    o32, d32 = _jit(o, d)
    expect = K.count_crossings_bspline(data, o32, d32, mi.Bool(True)).numpy()
    assert np.array_equal(_count_in_loop(data, o32, d32).numpy(), expect)


def test_walk_on_a_table_of_profiles():
    """The kernels on a view of concatenated profiles (kernels/top_level.py),
    R and R^2 forms mixed, count as on each profile's own data."""
    datas = [L.curve_data("glass12"), _surface_data(*OTHER_KINDS[0])]
    table = ProfileTable("bspline", datas, [True, True])
    for k, data in enumerate(datas):
        o, d = _rays(data, 4000, 5 + k)
        o32, d32 = _jit(o, d)
        view = table.view(dr.full(mi.UInt32, k, len(o)), mi.Bool(True))
        own = K.count_crossings_bspline(data, o32, d32, mi.Bool(True)).numpy()
        assert np.array_equal(K.count_crossings_bspline(view, o32, d32, mi.Bool(True)).numpy(), own)
        walked = _count_in_loop(view, o32, d32).numpy()
        assert np.array_equal(walked, own)


@CUDA_ROUNDING
@pytest.mark.parametrize("copies", [1, 3])
@pytest.mark.slow
def test_lathe_path_walk_through_bspline_has_no_odd_count(copies):
    """Rays walked as lathe_path walks them (spawn_ray past every hit, the
    walked line carried from hit to hit) through the paper's B-spline glass,
    alone or in a lathe set: no odd crossing count (the lathe's query on
    the spawned rays alone, and Mitsuba's mesh, have some)."""
    counts = leaks.scene_parity_leaks(str(ROOT / "scenes" / "paper" / "glass_bspline.csv"), 20_000, seed=5,
                                      kind="bspline", copies=copies)
    assert counts["hitting_exact"] > 15_000
    assert counts["odd_exact"] == 0
    assert counts["odd_offset"] <= counts["odd_mesh"]
    assert counts["stuck_exact"] == 0
