"""The user's units do not change what the kernels report (issue 10).

A profile and its rays scaled together by any factor give the same hits:
hit/miss, segment, ``t`` (in proportion), normals, and ``dp_du``/``dp_dv``
(in proportion), with no NaN or Inf in any field of a hit. Hypothesis draws
the scale (1e-6 .. 1e6) and the rays; the float32 extremes 1e-30 and 1e20
are explicit cases. ``LATHE_FUZZ_EXAMPLES`` sets the number of examples.
"""

from __future__ import annotations

import os

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from lathe_shape.kernels.bspline import bspline_geometry, build_bspline_data, intersect_bspline
from lathe_shape.kernels.polyline import build_polyline_data, intersect_polyline, polyline_geometry
from lathe_shape.validation import reference as ref

EXAMPLES = int(os.environ.get("LATHE_FUZZ_EXAMPLES", "25"))
KINDS = ("polyline", "bspline")
POLYLINE = ref.test_profiles(np.random.default_rng(11))[4][1]  # the glass
BSPLINE = ref.bspline_curve("glass12")[0]


def build(kind: str, scale: float):
    """Kernel data of the kind's test profile scaled by ``scale``."""
    if kind == "polyline":
        start, end = ref.segment_points(POLYLINE)
        return build_polyline_data(start * scale, end * scale)
    return build_bspline_data(BSPLINE * scale)


def unit_rays(kind: str, rng: np.random.Generator, n: int):
    """Rays from a sphere around the profile (size about 1) aimed at random
    points of its bounding box: ``(o, d)`` float64."""
    pts = (np.concatenate(ref.segment_points(POLYLINE)) if kind == "polyline"
           else BSPLINE.reshape(-1, 2))
    r_max, z_lo, z_hi = np.abs(pts[:, 0]).max(), pts[:, 1].min(), pts[:, 1].max()
    v = rng.normal(size=(n, 3))
    o = 3 * max(r_max, z_hi - z_lo) * v / np.linalg.norm(v, axis=1, keepdims=True)
    o[:, 2] += 0.5 * (z_lo + z_hi)
    target = np.stack([rng.uniform(-r_max, r_max, n), rng.uniform(-r_max, r_max, n),
                       rng.uniform(z_lo, z_hi, n)], axis=1)
    return o, target - o


def trace(kind: str, data, o: np.ndarray, d: np.ndarray) -> dict:
    """The kernel's hits and geometry of float32 rays, as numpy arrays."""
    o32 = mi.Point3f(o.T.astype(np.float32))
    d32 = mi.Vector3f(d.T.astype(np.float32))
    inf = dr.full(mi.Float, dr.inf, len(o))
    active = dr.full(mi.Bool, True, len(o))
    if kind == "polyline":
        hit = intersect_polyline(data, o32, d32, inf, active)
    else:
        hit = intersect_bspline(data, o32, d32, inf, active)
    # As the plugin does: geometry at the hit, at the origin on a miss
    p = dr.select(hit.valid, o32 + dr.select(hit.valid, hit.t, 0) * d32, 0)
    if kind == "polyline":
        geo = polyline_geometry(data, p, hit.seg, hit.u, True)
    else:
        geo = bspline_geometry(data, p, hit.seg, hit.u)
    out = {"t": hit.t, "seg": hit.seg, "u": hit.u, "valid": hit.valid, "n": geo.n,
           "sh_n": geo.sh_n, "uv": geo.uv, "dp_du": geo.dp_du, "dp_dv": geo.dp_dv}
    return {key: np.array(value, dtype=np.float64 if key != "valid" else bool).T
            for key, value in out.items()}


def assert_same_hits(kind: str, scale: float, d_scale: float, seed: int, n: int = 400) -> None:
    """The hits of the scaled profile and rays match those at scale 1."""
    o, d = unit_rays(kind, np.random.default_rng(seed), n)
    base = trace(kind, build(kind, 1.0), o, d)
    scaled = trace(kind, build(kind, scale), o * scale, d * d_scale)
    valid = base["valid"]
    assert valid.sum() > n // 10
    assert np.array_equal(scaled["valid"], valid), (kind, scale, np.nonzero(scaled["valid"] != valid))
    for key, value in scaled.items():
        assert np.all(np.isfinite(value[valid])), (kind, scale, key)
    assert np.all(np.isinf(scaled["t"][~valid]))
    assert np.all(np.isfinite(scaled["u"])) and np.all(np.isfinite(scaled["seg"]))
    # Transversal hits away from the joints are well conditioned: compare
    cos = np.abs(np.sum(base["n"] * d, axis=1)) / np.linalg.norm(d, axis=1)
    u_in = (base["u"] > 1e-3) & (base["u"] < 1 - 1e-3)
    firm = valid & (cos > 0.05) & u_in
    assert np.array_equal(scaled["seg"][firm], base["seg"][firm])
    t_ratio = scale / d_scale
    assert np.allclose(scaled["t"][firm] / t_ratio, base["t"][firm], rtol=2e-5, atol=2e-5)
    for key in ("n", "sh_n", "uv"):
        assert np.allclose(scaled[key][firm], base[key][firm], atol=2e-4), key
    for key in ("dp_du", "dp_dv"):
        size = np.linalg.norm(base[key][firm], axis=1, keepdims=True)
        assert np.allclose(scaled[key][firm] / scale, base[key][firm], rtol=1e-3, atol=1e-4 * size.max()), key


@settings(max_examples=EXAMPLES, deadline=None)
@given(kind=st.sampled_from(KINDS), log_scale=st.floats(-6, 6),
       log_d=st.floats(-3, 3), seed=st.integers(0, 2**32 - 1))
def test_scaled_hits_agree(kind: str, log_scale: float, log_d: float, seed: int) -> None:
    assert_same_hits(kind, 10.0 ** log_scale, 10.0 ** log_d, seed)


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("scale", [1e-30, 1e20])
def test_extreme_scales(kind: str, scale: float) -> None:
    """A profile 1e-30 or 1e20 across renders like one of size 1."""
    assert_same_hits(kind, scale, 1.0, 5)


@pytest.mark.parametrize("kind", KINDS)
def test_non_finite_rays_miss(kind: str) -> None:
    """Rays with NaN or infinite origins or directions miss, with finite
    ``u`` and ``seg``."""
    o, d = unit_rays(kind, np.random.default_rng(3), 12)
    bad = np.array([np.nan, np.inf, -np.inf])
    o[:9, np.arange(9) % 3] = bad[np.arange(9) // 3]
    d[9:, 0] = bad
    out = trace(kind, build(kind, 1.0), o, d)
    assert not out["valid"].any()
    assert np.all(np.isinf(out["t"]))
    for key in ("u", "seg", "n", "sh_n", "uv", "dp_du", "dp_dv"):
        assert np.all(np.isfinite(out[key])), key


def test_size_beyond_float32_is_refused() -> None:
    start, end = ref.segment_points(POLYLINE)
    with pytest.raises(ValueError, match="build_polyline_data.*size"):
        build_polyline_data(start * 1e40, end * 1e40)
