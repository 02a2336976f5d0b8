"""Watertightness measurements of the lathe kernels (tests and scripts).

A kernel leaks when a ray crosses the surface without a reported hit. Two
measurements follow rays through all their hits:

* :func:`crossing_leaks` (polyline lathes): the float64 inside test of
  :mod:`lathe_shape.validation.reference` checks every free stretch of the ray
  between hits, with :func:`polyline_callback` wrapping the kernel;
* :func:`bspline_leak_rate` (B-spline lathes): a ray entering a closed
  solid from outside must be crossed an even number of times;
* :func:`spawn_walk` and :func:`scene_parity_leaks` (any lathe, e.g. the
  closed profiles of ``scenes/*.csv``): the same parity count, walked the
  way integrators walk (``si.spawn_ray`` past every hit: the restart is
  offset along the geometric normal by Mitsuba's ray epsilon), through
  ``lathe_path``'s scene geometry (which carries the walked line from hit
  to hit, see :mod:`lathe_shape.plugin.line_walk`), through the lathe's
  own query on the spawned rays alone, and through Mitsuba's own mesh of
  the lathe, on the same rays; :func:`refraction_walk` follows rays that
  refract at every hit instead.

Needs an active JIT Mitsuba variant.
"""

from __future__ import annotations

import argparse
from collections.abc import Callable
from functools import partial

import drjit as dr
import mitsuba as mi
import numpy as np

from ..kernels.bspline import build_bspline_data, intersect_bspline
from ..kernels.polyline import (
    PolylineData,
    build_polyline_data,
    intersect_polyline,
    next_crossing_polyline,
    polyline_geometry,
)
from ..profiles import read_profile_options
from . import reference as ref

__all__ = [
    "leak_test_arguments",
    "polyline_callback",
    "crossing_leaks",
    "bspline_leak_rate",
    "parity_rays",
    "spawn_walk",
    "crossing_walk",
    "scene_parity_leaks",
    "random_profile_leaks",
    "parity_summary",
    "solid_profile_files",
]


def leak_test_arguments(description: str, argv: list[str] | None = None,
                        random_profiles: bool = True) -> argparse.Namespace:
    """The leak test scripts' options, parsed from ``argv`` (default: the
    command line): the number of rays in all (``--rays N`` or positionally,
    default 1e6), ``--variant``, ``--chunk``, ``--mesh-segments`` and, when
    ``random_profiles`` (``scripts/leak_test.py``), ``--random-profiles``
    (the crossing test on random profiles instead of the spawn-ray parity
    walk through ``scenes/*.csv``). Selects the Mitsuba variant."""
    from ..cli.common import DEFAULT_VARIANT

    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("n_rays", nargs="?", type=float, default=None, help="rays in all (default: 1e6)")
    parser.add_argument("--rays", type=float, default=None, help="rays in all (default: 1e6)")
    parser.add_argument("--variant", default=DEFAULT_VARIANT,
                        help=f"Mitsuba JIT variant (default: {DEFAULT_VARIANT})")
    if random_profiles:
        parser.add_argument("--random-profiles", action="store_true",
                            help="polylines: the float64 crossing test on random profiles "
                                 "(default: the parity walk through scenes/*.csv)")
    parser.add_argument("--chunk", type=int, default=250_000, help="rays per batch (default: 250000)")
    parser.add_argument("--mesh-segments", type=int, default=512,
                        help="azimuthal steps of the compared mesh (default: 512)")
    args = parser.parse_args(argv)
    mi.set_variant(args.variant)
    args.n_rays = int(args.rays or args.n_rays or 1e6)
    return args


def polyline_callback(data: PolylineData) -> Callable:
    """The polyline kernel on numpy rays, as :func:`crossing_leaks` wants it:
    ``intersect(o, d, active) -> (t, valid, n)`` with float64 ``(n, 3)``
    arrays ``o``, ``d`` (rounded to float32) and the geometric normal ``n``
    at the hits."""
    def intersect(o, d, active):
        o32 = mi.Point3f(o.T.astype(np.float32))
        d32 = mi.Vector3f(d.T.astype(np.float32))
        hit = intersect_polyline(data, o32, d32, dr.full(mi.Float, dr.inf, len(o)),
                                 mi.Bool(active))
        p = o32 + dr.select(hit.valid, hit.t, 0) * d32
        geo = polyline_geometry(data, p, hit.seg, hit.u, False)
        return (hit.t.numpy().astype(np.float64), hit.valid.numpy(),
                geo.n.numpy().T.astype(np.float64))
    return intersect


def crossing_leaks(intersect: Callable, prof, o: np.ndarray, d: np.ndarray, off_rel: float = 1e-4,
                   max_hits: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """Follow rays through all their hits and flag leaks.

    ``intersect(o, d, active) -> (t, valid, n)`` is the kernel under test
    (numpy in and out, ``n`` the geometric normal at the hit). After each
    hit the ray restarts from the hit point moved ``off_rel * scale`` along
    the normal to the far side (as ``spawn_ray`` does) and as much along the
    ray (so that rays through a corner leave it). Between two
    consecutive hits (a *free segment*) the ray must stay on one side of the
    surface: the inside test (float64, exact) at 1/4, 1/2 and 3/4 of every
    free segment must agree, the segment before the first hit must match the
    state of ``o``, and the segment after the last hit must be outside. A ray
    breaking one of these crossed the surface without a reported hit: a leak.
    Sampling inside the free segments (not right at the hits) keeps the
    float32 position noise of grazing hits from being counted.

    Returns ``(leak, n_hits)`` per ray.
    """
    _, z_min, z_max, scale = ref.bounds(prof)
    centre = np.array([0.0, 0.0, 0.5 * (z_min + z_max)])
    radius = 2.0 * scale
    o = np.asarray(o, dtype=np.float64).copy()
    d = np.asarray(d, dtype=np.float64)
    dn2 = np.sum(d * d, axis=1)
    off = off_rel * scale

    def t_exit(orig):
        # Ray parameter where the ray leaves the bounding sphere
        oc = orig - centre
        b = np.sum(oc * d, axis=1)
        c = np.sum(oc * oc, axis=1) - radius**2
        disc = np.maximum(b * b - dn2 * c, 0)
        return np.maximum((-b + np.sqrt(disc)) / dn2, 0)

    start_inside = ref.inside_profile(prof, o)
    leak = np.zeros(len(o), dtype=bool)
    n_hits = np.zeros(len(o), dtype=np.int64)
    active = np.ones(len(o), dtype=bool)
    for k in range(max_hits):
        t, valid, n = intersect(o, d, active)
        valid = valid & active
        t_end = np.where(valid, t, t_exit(o))
        states = [ref.inside_profile(prof, o + (f * t_end)[:, None] * d)
                  for f in (0.25, 0.5, 0.75)]
        mixed = (states[0] != states[1]) | (states[1] != states[2])
        leak |= active & mixed
        if k == 0:
            leak |= active & (states[1] != start_inside)
        # After the last hit the ray must be outside
        leak |= active & ~valid & states[1]
        n_hits += valid
        side = np.where(np.sum(n * d, axis=1) >= 0, 1.0, -1.0)
        t_off = np.where(valid, t + off / np.sqrt(dn2), 0)
        p = o + t_off[:, None] * d + (side * off)[:, None] * n
        o = np.where(valid[:, None], p, o)
        active = valid
        if not active.any():
            break
    return leak, n_hits


def bspline_leak_rate(curve: str, n: int, seed: int) -> tuple[float, int]:
    """``(rate, entered)``: of ``n`` rays from outside aimed at the test curve
    ``curve`` (see :func:`lathe_shape.validation.reference.bspline_rays`), the
    ``entered`` ones that hit it, and the fraction of those crossing it an
    odd number of times. After each hit a ray restarts ``1e-4`` of the
    curve's size past it."""
    seg, _ = ref.bspline_curve(curve)
    data = build_bspline_data(seg)
    rng = np.random.default_rng(seed)
    org, d = ref.bspline_rays("outside", seg, rng, n)
    d /= np.linalg.norm(d, axis=1)[:, None]
    scale = float(np.linalg.norm(np.ptp(seg.reshape(-1, 2), axis=0)))
    o = mi.Point3f(org.T.astype(np.float32))
    dj = mi.Vector3f(d.T.astype(np.float32))
    active = mi.Bool(np.ones(n, bool))
    count = mi.UInt32(0)
    eps = 1e-4 * scale
    for _ in range(16):
        hit = intersect_bspline(data, o, dj, mi.Float(dr.inf), active)
        active &= hit.valid
        count += mi.UInt32(active)
        o = dr.select(active, dr.fma(dj, hit.t + eps, o), o)
        dr.eval(o, active, count)
        if not dr.any(active):
            break
    count = np.array(count)
    entered = count > 0
    return np.mean(count[entered] % 2 == 1), int(entered.sum())


# ---------------------------------------------------------------------------
# Spawn-ray parity walk (exact kernel vs Mitsuba's mesh)
# ---------------------------------------------------------------------------

def parity_rays(start: np.ndarray, end: np.ndarray, rng: np.random.Generator,
                n: int) -> tuple[np.ndarray, np.ndarray]:
    """``n`` rays ``(o, d)`` (float64, unit ``d``) from outside the lathe of
    the profile segments ``start -> end`` (``(m, 2)`` each): origins on a
    sphere of twice the profile's size around it. In equal shares they aim at
    random points of the bounding box, at random points of the surface,
    exactly at profile vertices (the joints) and next to them (grazing
    convex corners: offsets of 1e-7 to 1e-3 of the size)."""
    points = np.concatenate([start, end])
    r_max = points[:, 0].max()
    z_lo, z_hi = points[:, 1].min(), points[:, 1].max()
    size = max(r_max, z_hi - z_lo)
    k = n // 4

    def revolve(rz):
        phi = rng.uniform(0, 2 * np.pi, len(rz))
        return np.stack([rz[:, 0] * np.cos(phi), rz[:, 0] * np.sin(phi), rz[:, 1]], axis=1)

    box = np.stack([rng.uniform(-r_max, r_max, k), rng.uniform(-r_max, r_max, k),
                    rng.uniform(z_lo, z_hi, k)], axis=1)
    seg = rng.integers(0, len(start), k)
    f = rng.uniform(0, 1, (k, 1))
    on_surface = revolve((1 - f) * start[seg] + f * end[seg])
    vertex = revolve(start[rng.integers(0, len(start), k)])
    m = n - 3 * k
    jitter = rng.normal(size=(m, 3))
    jitter *= size * 10.0 ** rng.uniform(-7, -3, (m, 1)) / np.linalg.norm(jitter, axis=1, keepdims=True)
    near = revolve(start[rng.integers(0, len(start), m)]) + jitter
    target = np.vstack([box, on_surface, vertex, near])
    v = rng.normal(size=(n, 3))
    o = 2 * size * v / np.linalg.norm(v, axis=1, keepdims=True) + [0, 0, 0.5 * (z_lo + z_hi)]
    d = target - o
    return o, d / np.linalg.norm(d, axis=1, keepdims=True)


def spawn_walk(intersect: Callable, o: np.ndarray, d: np.ndarray,
               max_hits: int = 64, walked: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Follow rays through all their hits as an integrator does.

    ``intersect(ray, active) -> mi.SurfaceInteraction3f`` is the query under
    test; after every hit the ray continues as ``si.spawn_ray(d)``. With
    ``walked``, ``intersect(ray, active, walk) -> (si, walk)`` carries the
    :class:`~lathe_shape.plugin.line_walk.LineWalk` from hit to hit, as
    ``lathe_path`` does. Returns ``(crossings, stuck)`` per ray: the number
    of hits, and whether the ray still hit something after ``max_hits``."""
    from ..plugin.line_walk import start_walk  # needs a variant set

    ray = mi.Ray3f(mi.Point3f(o.T.astype(np.float32)), mi.Vector3f(d.T.astype(np.float32)))
    active = dr.full(mi.Bool, True, len(o))
    count = dr.zeros(mi.UInt32, len(o))
    walk = start_walk(len(o)) if walked else None
    for _ in range(max_hits):
        if walked:
            si, walk = intersect(ray, active, walk)
        else:
            si = intersect(ray, active)
        active &= si.is_valid()
        count += mi.UInt32(active)
        ray = dr.select(active, si.spawn_ray(ray.d), ray)
        dr.eval(ray, active, count, walk)
        if not dr.any(active):
            break
    return count.numpy().astype(np.int64), active.numpy()


def refraction_walk(intersect: Callable, o: np.ndarray, d: np.ndarray, eta: float = 1.5,
                    max_hits: int = 24, walked: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Follow rays that refract (index ``eta`` inside, total internal
    reflection where it occurs) at every hit of a closed solid, restarted
    with ``si.spawn_ray`` as integrators do (``intersect`` and ``walked`` as
    in :func:`spawn_walk`), keeping track of inside and outside. A ray is
    inconsistent when it enters
    while inside, leaves while outside, or escapes from inside (a skipped
    or doubled crossing); ``stuck`` as in :func:`spawn_walk`. The geometric
    normal decides, so no shading normal can make a ray turn back. Returns
    ``(hits, inconsistent, stuck)`` per ray, ``hits`` the number of hits."""
    from ..plugin.line_walk import start_walk  # needs a variant set

    ray = mi.Ray3f(mi.Point3f(o.T.astype(np.float32)), mi.Vector3f(d.T.astype(np.float32)))
    active = dr.full(mi.Bool, True, len(o))
    inside = dr.full(mi.Bool, False, len(o))
    wrong = dr.full(mi.Bool, False, len(o))
    hits = dr.zeros(mi.UInt32, len(o))
    walk = start_walk(len(o)) if walked else None
    for _ in range(max_hits):
        si, walk = intersect(ray, active, walk) if walked else (intersect(ray, active), None)
        hit = active & si.is_valid()
        entering = dr.dot(ray.d, si.n) < 0
        wrong |= (hit & (entering == inside)) | (active & ~hit & inside)
        hits += mi.UInt32(hit)
        # Snell's law about the normal facing the ray (eqs. of any textbook)
        n = dr.select(entering, si.n, -si.n)
        ratio = dr.select(entering, 1.0 / eta, eta)
        cos_i = -dr.dot(ray.d, n)
        k = 1.0 - ratio * ratio * (1.0 - cos_i * cos_i)
        reflected = k < 0
        refracted = ratio * ray.d + (ratio * cos_i - dr.sqrt(dr.maximum(k, 0.0))) * n
        d_next = dr.normalize(dr.select(reflected, ray.d + 2.0 * cos_i * n, refracted))
        inside = dr.select(hit, entering != reflected, inside)
        active = hit & ~wrong
        ray = dr.select(active, si.spawn_ray(d_next), ray)
        dr.eval(ray, active, inside, wrong, hits, walk)
        if not dr.any(active):
            break
    return hits.numpy().astype(np.int64), wrong.numpy(), active.numpy()


def crossing_walk(data: PolylineData, o: np.ndarray, d: np.ndarray,
                  max_hits: int = 64) -> tuple[np.ndarray, np.ndarray]:
    """Follow rays through all their crossings with a polyline lathe (local
    frame) the way an integrator can without offsets: every query keeps the
    ray's first origin and asks for the crossing after the one just taken
    (:func:`~lathe_shape.kernels.polyline.next_crossing_polyline`). Returns
    ``(crossings, stuck)`` as :func:`spawn_walk`."""
    o32 = mi.Point3f(o.T.astype(np.float32))
    d32 = mi.Vector3f(d.T.astype(np.float32))
    tmax = dr.full(mi.Float, dr.inf, len(o))
    active = dr.full(mi.Bool, True, len(o))
    count = dr.zeros(mi.UInt32, len(o))
    after_s, after_key = None, None
    for _ in range(max_hits):
        hit, s, key = next_crossing_polyline(data, o32, d32, tmax, active, after_s, after_key)
        active &= hit.valid
        count += mi.UInt32(active)
        after_s, after_key = s, key
        dr.eval(after_s, after_key, active, count)
        if not dr.any(active):
            break
    return count.numpy().astype(np.int64), active.numpy()


def scene_parity_leaks(filename: str, n: int, seed: int, mesh_segments: int = 512,
                       chunk: int = 250_000, kind: str | None = None, copies: int = 1,
                       refract: bool = False) -> dict[str, int]:
    """Spawn-ray parity walk through the lathe of the profile file
    ``filename`` (a closed solid, local frame = world), in chunks of
    ``chunk`` rays (``kind``: the lathe's profile kind, default the file's
    own), on the same :func:`parity_rays` for every query, each walked with
    ``si.spawn_ray`` past every hit (:func:`spawn_walk`):

    * ``exact``: the scene geometry of ``lathe_path``
      (``ExactSceneGeometry.ray_intersect_walk``), which carries the walked
      line from hit to hit;
    * ``offset``: the lathe's own query (``ray_intersect_exact``) on the
      spawned rays alone, each restarted off the surface;
    * ``mesh``: Mitsuba's mesh of the lathe (``mesh_segments`` azimuthal
      steps, the scene's own accelerator);
    * ``walk``: the kernel walked without offsets (:func:`crossing_walk`,
      polyline profiles only);
    * with ``refract``, ``refract`` and ``refract_mesh``: rays refracted at
      every hit (:func:`refraction_walk`) through the scene geometry and
      through Mitsuba's mesh; their "odd" count is the inconsistent rays.

    ``copies`` > 1 adds that many more copies of the lathe far from the
    first (the rays aim at the first), so that the scene geometry walks
    them as one lathe set (kernels/top_level.py). Every ray starts outside,
    so an odd number of crossings is a leak. Returns the counts ``rays`` and per query ``hitting_<query>``,
    ``odd_<query>``, ``stuck_<query>``."""
    from ..plugin.scene_geometry import ExactSceneGeometry  # needs a variant set

    lathe_props = {"type": "lathe", "filename": filename, "mesh_segments": mesh_segments}
    lathe_props |= {"kind": kind} if kind else {}
    far = [{**lathe_props, "mesh_segments": 3, "to_world": mi.ScalarTransform4f().translate([1e4 * k, 0, 0])}
           for k in range(1, copies)]
    scene = mi.load_dict({"type": "scene", "lathe": lathe_props} | {f"far_{k}": p for k, p in enumerate(far)})
    lathe = scene.shapes()[0]
    exact = ExactSceneGeometry(scene).ray_intersect_walk
    mesh = lambda ray, active: scene.ray_intersect(ray, active=active)  # noqa: E731
    walks = {"exact": _odd_counts(partial(spawn_walk, exact, walked=True)),
             "offset": _odd_counts(partial(spawn_walk, lathe.ray_intersect_exact)),
             "mesh": _odd_counts(partial(spawn_walk, mesh))}
    if isinstance(lathe.surface.data, PolylineData):
        walks["walk"] = _odd_counts(partial(crossing_walk, lathe.surface.data))
    if refract:
        walks |= {"refract": partial(refraction_walk, exact, walked=True),
                  "refract_mesh": partial(refraction_walk, mesh)}
    if "walk" in walks:
        start, end = lathe.profile.segment_points()
    else:
        # B-splines: the reference mesh's profile samples stand for vertices
        points = lathe.surface.profile_samples[0]
        points = points[np.r_[True, np.any(points[1:] != points[:-1], axis=1)]]  # (a corner's two rings)
        start, end = points[:-1], points[1:]
    rng = np.random.default_rng(seed)
    counts = {"rays": 0} | {f"{what}_{name}": 0 for name in walks for what in ("hitting", "odd", "stuck")}
    for done in range(0, n, chunk):
        o, d = parity_rays(start, end, rng, min(chunk, n - done))
        counts["rays"] += len(o)
        for name, walk in walks.items():
            hits, wrong, stuck = walk(o, d)
            counts[f"hitting_{name}"] += int(np.sum(hits > 0))
            counts[f"odd_{name}"] += int(np.sum(wrong))
            counts[f"stuck_{name}"] += int(np.sum(stuck))
    return counts


def _odd_counts(walk: Callable) -> Callable:
    """A walk returning ``(crossings, stuck)`` as one returning ``(hits,
    odd, stuck)`` (:func:`scene_parity_leaks`)."""
    def run(o: np.ndarray, d: np.ndarray):
        crossings, stuck = walk(o, d)
        return crossings, crossings % 2 == 1, stuck
    return run


def random_profile_leaks(n_rays: int, seed: int = 2024,
                         chunk: int = 200_000) -> list[tuple[str, int, int, int]]:
    """:func:`crossing_leaks` of the polyline kernel over ``n_rays`` rays in
    all, shared among the random closed test profiles of
    :func:`lathe_shape.validation.reference.test_profiles` (rays of
    :func:`lathe_shape.validation.reference.random_rays` that start outside).
    Returns ``(name, rays, hitting, leaks)`` per profile."""
    rng = np.random.default_rng(seed)
    profiles = ref.test_profiles(rng)
    per_profile = n_rays // len(profiles) + 1
    rows = []
    for name, prof in profiles:
        intersect = polyline_callback(build_polyline_data(*ref.segment_points(prof)))
        n_leaks = hits = rays = 0
        while rays < per_profile:
            m = min(chunk, per_profile - rays)
            # Oversample, then keep only rays starting outside the solid
            o, d = ref.random_rays(rng, prof, 2 * m)
            o = o.astype(np.float32).astype(np.float64)
            d = d.astype(np.float32).astype(np.float64)
            keep = ~ref.inside_profile(prof, o)
            leak, n_hits = crossing_leaks(intersect, prof, o[keep][:m], d[keep][:m])
            rays += len(leak)
            hits += int(np.sum(n_hits > 0))
            n_leaks += int(np.sum(leak))
        rows.append((name, rays, hits, n_leaks))
    return rows


def parity_summary(name: str, counts: dict[str, int],
                   kinds: tuple[str, ...] = ("exact", "offset", "mesh", "walk")) -> str:
    """One line of :func:`scene_parity_leaks` counts: the odd (leaking,
    or for refraction walks inconsistent) rays of each walk of ``kinds``
    present, per hitting ray."""
    parts = [f"{name:14s} rays {counts['rays']:9d}"]
    for kind in kinds:
        if f"hitting_{kind}" not in counts:
            continue
        hits, odd = counts[f"hitting_{kind}"], counts[f"odd_{kind}"]
        parts.append(f"{kind}: hitting {hits:9d} odd {odd:5d} ({odd / max(hits, 1):.1e})"
                     + (f" stuck {counts[f'stuck_{kind}']}" if counts[f"stuck_{kind}"] else ""))
    return "  ".join(parts)


def solid_profile_files(paths) -> list:
    """The profile files among ``paths`` that bound solids: those that do
    not declare ``# open: true`` (an open sheet, such as the filled wine
    glass's, has no inside, so a parity count means nothing for it)."""
    return [path for path in paths if not read_profile_options(str(path)).get("open", False)]
