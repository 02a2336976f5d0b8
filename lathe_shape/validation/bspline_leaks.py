"""Watertightness of the B-spline kernel walked without offsets.

A ray from outside a closed lathe must cross it an even number of times.
:func:`crossing_walk_bspline` follows rays through their crossings with
:func:`~lathe_shape.kernels.bspline.next_crossing_bspline` (the first
origin kept, each query asking for the crossing after the one just taken),
and :func:`walk_parity_leaks` counts the odd ones over the rays of
:func:`lathe_shape.validation.leaks.parity_rays`, aimed at random points, at
the leaves' joints and next to them, for any cubic-kind lathe data: the
B-spline test curves (:func:`curve_data`) or the points of a profile file
taken as B-spline control points (:func:`profile_file_data`). The same rays are also counted in
one query (:func:`~lathe_shape.kernels.bspline.count_crossings_bspline`).

Needs an active JIT Mitsuba variant.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from ..kernels.bspline import (
    _LEAF_STRIDE,
    BSplineData,
    build_bspline_data,
    count_crossings_bspline,
    next_crossing_bspline,
)
from ..profiles.bspline import make_bspline_profile
from ..profiles.sources import read_points
from . import reference as ref
from .leaks import parity_rays

__all__ = ["leaf_joints", "curve_data", "profile_file_data", "crossing_walk_bspline",
           "walk_parity_leaks", "walk_leak_table", "walk_summary"]


def leaf_joints(data: BSplineData) -> np.ndarray:
    """The ``(r, z)`` start points of the leaves of ``data`` and the end of
    the last one (local frame, float64): the joints where two leaves meet."""
    leaf = np.asarray(data.leaf.numpy(), dtype=np.float64).reshape(-1, _LEAF_STRIDE)
    size = float(data.scale.numpy()[0])
    shift = float(data.z_shift.numpy()[0])
    r = np.append(leaf[:, 0], leaf[-1, 3])
    if data.r_squared:
        r = np.sqrt(np.maximum(r, 0.0))
    z = np.append(leaf[:, 4], leaf[-1, 7])
    return np.stack([r * size, (z - shift) * size], axis=1)


def curve_data(name: str) -> BSplineData:
    """Kernel data of the B-spline test curve ``name`` (a key of
    :data:`lathe_shape.validation.reference.BSPLINE_CURVES`)."""
    return build_bspline_data(ref.bspline_curve(name)[0])


def profile_file_data(filename: str) -> BSplineData:
    """Kernel data of the points of the profile file ``filename`` read as
    the control points of a cubic B-spline (sharp flags ignored: a spline
    has none)."""
    points = read_points(filename)[0]
    return build_bspline_data(make_bspline_profile(points, filename).segment_controls)


def crossing_walk_bspline(data: BSplineData, o: np.ndarray, d: np.ndarray,
                          max_hits: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """Follow the rays ``o + t d`` (float64 ``(n, 3)``, rounded to float32)
    through all their crossings with the lathe of ``data`` without offsets
    (:func:`~lathe_shape.kernels.bspline.next_crossing_bspline`, in one
    symbolic loop, as an integrator would). Returns ``(crossings, stuck)``
    per ray: the number of crossings found, and whether a ray still found
    one after ``max_hits``."""
    count, active = _walk(data, mi.Point3f(o.T.astype(np.float32)), mi.Vector3f(d.T.astype(np.float32)),
                          max_hits)
    return count.numpy().astype(np.int64), active.numpy()


@dr.syntax
def _walk(data: BSplineData, o: mi.Point3f, d: mi.Vector3f, max_hits: int):
    """The symbolic loop of :func:`crossing_walk_bspline`."""
    count = dr.zeros(mi.UInt32, dr.width(o))     # crossings found so far
    active = dr.full(mi.Bool, True, dr.width(o))  # the ray may find more
    s = dr.full(mi.Float, -dr.inf, dr.width(o))  # the last crossing's place ...
    key = dr.full(mi.UInt32, 0xFFFFFFFF, dr.width(o))  # ... and key (none yet)
    while active & (count < max_hits):
        hit, s_next, key_next = next_crossing_bspline(data, o, d, mi.Float(dr.inf), active, s, key)
        active &= hit.valid
        count = dr.select(active, count + 1, count)
        s = dr.select(active, s_next, s)
        key = dr.select(active, key_next, key)
    return count, active


def walk_parity_leaks(data: BSplineData, n: int, seed: int, chunk: int = 250_000) -> dict[str, int]:
    """Parity of :func:`crossing_walk_bspline` and of
    :func:`~lathe_shape.kernels.bspline.count_crossings_bspline` over ``n``
    rays from outside (:func:`~lathe_shape.validation.leaks.parity_rays` with the
    leaf joints as vertices), in chunks of ``chunk`` rays. Returns the
    counts ``rays``, ``hitting`` (walk), ``odd_walk``, ``stuck``,
    ``odd_count`` and ``disagree`` (rays whose walk and count differ)."""
    joints = leaf_joints(data)
    rng = np.random.default_rng(seed)
    counts = dict.fromkeys(("rays", "hitting", "odd_walk", "stuck", "odd_count", "disagree"), 0)
    for done in range(0, n, chunk):
        o, d = parity_rays(joints[:-1], joints[1:], rng, min(chunk, n - done))
        walked, stuck = crossing_walk_bspline(data, o, d)
        counted = count_crossings_bspline(data, mi.Point3f(o.T.astype(np.float32)),
                                          mi.Vector3f(d.T.astype(np.float32)),
                                          dr.full(mi.Bool, True, len(o))).numpy()
        counts["rays"] += len(o)
        counts["hitting"] += int(np.sum(walked > 0))
        counts["odd_walk"] += int(np.sum(walked % 2 == 1))
        counts["stuck"] += int(np.sum(stuck))
        counts["odd_count"] += int(np.sum(counted % 2 == 1))
        counts["disagree"] += int(np.sum(counted != walked))
    return counts


def walk_leak_table(files: list[str], n_rays: int, seed: int = 3,
                    chunk: int = 250_000) -> list[tuple[str, dict[str, int]]]:
    """:func:`walk_parity_leaks` over ``n_rays`` rays in all, shared among
    the B-spline test curves and the profile files ``files`` (as B-spline
    control points, :func:`profile_file_data`). Returns ``(name, counts)``
    per profile and a last row ``("total", counts)``."""
    names = [*ref.BSPLINE_CURVES, *files]
    rows, total = [], {}
    for k, name in enumerate(names):
        data = curve_data(name) if name in ref.BSPLINE_CURVES else profile_file_data(name)
        counts = walk_parity_leaks(data, n_rays // len(names), seed + k, chunk)
        rows.append((name, counts))
        total = {key: total.get(key, 0) + value for key, value in counts.items()}
    return rows + [("total", total)]


def walk_summary(name: str, counts: dict[str, int]) -> str:
    """One line of :func:`walk_parity_leaks` counts."""
    return (f"{name:28s} rays {counts['rays']:9d} hitting {counts['hitting']:9d} "
            f"odd walk {counts['odd_walk']:4d} odd count {counts['odd_count']:4d} "
            f"walk != count {counts['disagree']:4d} stuck {counts['stuck']}")
