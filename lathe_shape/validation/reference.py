"""Float64 numpy references and test data for the lathe kernels.

Polyline lathes, brute force and independent of the kernel: every segment is
intersected in the paper's own form (docs/method.md eqs. 1-7): a cone
frustum / cylinder ``x^2 + y^2 = (A z + B)^2`` restricted to its z range with
``A z + B >= 0``, or a flat annulus ``z = z0``, ``min(r)^2 <= x^2 + y^2 <=
max(r)^2``. The nearest hit with ``t > t_min`` over all segments wins. Test
profiles are ``(r0, z0, r1, z1)`` tuples of segment arrays.

B-spline lathes: the test curves (:data:`BSPLINE_CURVES`) and the ray sets
around them (:func:`bspline_rays`) shared by the tests and the scripts.
"""

from __future__ import annotations

import numpy as np

from ..profiles import bspline as bs

#: B-spline test curves (control points): a glass-wall ring (closed periodic
#: B-spline: thick base, thin wall, rim), an egg / vase (open B-spline, both
#: ends on the axis) and a 12-segment closed glass profile.
BSPLINE_CURVES = {
    "ring": np.array([[1.0, 0.0], [1.2, 0.0], [1.2, 1.5], [1.1, 2.0], [1.0, 1.5],
                      [1.0, 0.2], [1.0, 0.0]]),
    "egg": np.array([[0.0, 0.0], [0.6, 0.0], [1.0, 0.6], [0.9, 1.5], [0.4, 2.0], [0.0, 2.1]]),
    "glass12": np.array([[0.0 + 0.3, 0.0], [0.9, 0.0], [1.0, 0.15], [0.5, 0.3], [0.3, 0.8],
                         [0.8, 1.4], [1.1, 2.4], [1.0, 2.5], [0.9, 2.4], [0.6, 1.5],
                         [0.15, 1.0], [0.2, 0.2], [0.3, 0.0]]),
}

#: Control points of the 12-segment spline glass of the benchmarks (open
#: form: both ends on the axis, ends tripled by the B-spline rules).
SPLINE_GLASS = np.array([
    (0, 0), (3.5, 0), (0.3, 0.3), (0.35, 4.5), (0.5, 7.2), (4.8, 8.8),
    (4.0, 18.4), (3.78, 18.4), (4.45, 9.4), (0.9, 7.7), (0, 7.6),
], dtype=float)


def intersect_reference(r0, z0, r1, z1, o, d, t_min=0.0):
    """Nearest hit of rays ``o + t d`` (arrays ``(n, 3)``) with the lathe.

    Returns ``(t, seg)``: ``t`` is ``inf`` and ``seg`` is -1 on a miss.
    """
    o = np.asarray(o, dtype=np.float64)
    d = np.asarray(d, dtype=np.float64)
    n = len(o)
    t_best = np.full(n, np.inf)
    seg_best = np.full(n, -1, dtype=np.int64)
    ox, oy, oz = o.T
    dx, dy, dz = d.T
    for i in range(len(r0)):
        if z0[i] == z1[i]:
            # Annulus in the plane z = z0
            with np.errstate(divide='ignore', invalid='ignore'):
                t = (z0[i] - oz) / dz
            x = ox + t * dx
            y = oy + t * dy
            rr = x * x + y * y
            lo, hi = min(r0[i], r1[i]), max(r0[i], r1[i])
            ok = (np.isfinite(t) & (t > t_min) & (rr >= lo * lo)
                  & (rr <= hi * hi))
            cands = [(t, ok)]
        else:
            # Cone frustum / cylinder x^2 + y^2 = (A z + B)^2
            a_ = (r1[i] - r0[i]) / (z1[i] - z0[i])
            b_ = (z1[i] * r0[i] - r1[i] * z0[i]) / (z1[i] - z0[i])
            g0 = a_ * oz + b_
            g1 = a_ * dz
            qa = dx * dx + dy * dy - g1 * g1
            qb = 2 * (ox * dx + oy * dy - g0 * g1)
            qc = ox * ox + oy * oy - g0 * g0
            disc = qb * qb - 4 * qa * qc
            sq = np.sqrt(np.maximum(disc, 0))
            with np.errstate(divide='ignore', invalid='ignore'):
                lin = np.abs(qa) < 1e-300
                ta = np.where(lin, -qc / qb, (-qb - sq) / (2 * qa))
                tb = np.where(lin, np.inf, (-qb + sq) / (2 * qa))
            zlo, zhi = min(z0[i], z1[i]), max(z0[i], z1[i])
            cands = []
            for t in (ta, tb):
                with np.errstate(invalid='ignore'):
                    z = oz + t * dz
                    ok = ((disc >= 0) & np.isfinite(t) & (t > t_min)
                          & (z >= zlo) & (z <= zhi) & (a_ * z + b_ >= 0))
                cands.append((t, ok))
        for t, ok in cands:
            better = ok & (t < t_best)
            t_best = np.where(better, t, t_best)
            seg_best = np.where(better, i, seg_best)
    return t_best, seg_best


def normal_reference(r0, z0, r1, z1, seg, p):
    """Outward unit normal (eqs. 8-9) at points ``p`` on segments ``seg``."""
    p = np.asarray(p, dtype=np.float64)
    r0, z0, r1, z1 = (np.asarray(a)[seg] for a in (r0, z0, r1, z1))
    x, y, z = p.T
    s_ = z0 - z1
    flat = s_ == 0
    with np.errstate(divide='ignore', invalid='ignore'):
        a_ = np.where(flat, 0.0, (r1 - r0) / np.where(flat, 1.0, z1 - z0))
        b_ = np.where(flat, 0.0, (z1 * r0 - r1 * z0)
                      / np.where(flat, 1.0, z1 - z0))
    n = np.stack([x * s_, y * s_, -a_ * (a_ * z + b_) * s_], axis=1)
    n_flat = np.stack([np.zeros_like(x), np.zeros_like(x),
                       r1 * r1 - r0 * r0], axis=1)
    n = np.where(flat[:, None], n_flat, n)
    norm = np.linalg.norm(n, axis=1, keepdims=True)
    with np.errstate(divide='ignore', invalid='ignore'):
        return n / norm


# ---------------------------------------------------------------------------
# Random closed profiles and rays for the tests and scripts
# ---------------------------------------------------------------------------

def segments(points):
    """Split a point list ``(m, 2)`` into segment arrays, dropping segments
    lying on the axis. Returns ``(r0, z0, r1, z1)``."""
    p = np.asarray(points, dtype=np.float64)
    r0, z0 = p[:-1].T
    r1, z1 = p[1:].T
    keep = ~((r0 == 0) & (r1 == 0))
    return r0[keep], z0[keep], r1[keep], z1[keep]


def star_profile(rng, n):
    """Closed star-shaped polygon around (1.5, 0) in r > 0, clockwise."""
    ang = np.sort(rng.uniform(0, 2 * np.pi, n))[::-1]
    rad = rng.uniform(0.4, 1.2, n)
    pts = np.stack([1.5 + rad * np.cos(ang), rad * np.sin(ang)], axis=1)
    return segments(np.vstack([pts, pts[:1]]))


def vase_profile(rng, n, flat_ends=True):
    """Solid of revolution with both ends on the axis (top to bottom)."""
    z = np.linspace(2.0, 0.0, n)
    r = 0.5 + 0.3 * np.sin(rng.uniform(1, 3) * z + rng.uniform(0, 6))
    r += rng.uniform(-0.05, 0.05, n)
    pts = np.stack([r, z], axis=1)
    if flat_ends:
        pts = np.vstack([[0.0, z[0]], pts, [0.0, z[-1]]])
    else:
        pts[0, 0] = 0.0
        pts[-1, 0] = 0.0
    return segments(pts)


def glass_profile(rng, n_wall):
    """Hollow cup with a solid base: annuli, cylinders and jittered walls."""
    zin = np.linspace(0.2, 2.0, n_wall)
    rin = 0.8 + rng.uniform(-0.02, 0.02, n_wall) * (rng.uniform() < 0.5)
    zout = np.linspace(2.0, 0.0, n_wall)
    rout = 0.9 + rng.uniform(-0.02, 0.02, n_wall) * (rng.uniform() < 0.5)
    pts = np.vstack([[[0.0, 0.2]], np.stack([rin, zin], axis=1),
                     np.stack([rout, zout], axis=1), [[0.0, 0.0]]])
    return segments(pts)


def ring_profile():
    """Square ring: two cylinders and two annuli."""
    return segments([(1, 0), (1, 1), (2, 1), (2, 0), (1, 0)])


def cone_profile():
    """Cone with its apex on the axis and a base disk."""
    return segments([(0, 1.5), (1, 0), (0, 0)])


def test_profiles(rng):
    """A list of ``(name, (r0, z0, r1, z1))`` valid closed profiles."""
    return [('star7', star_profile(rng, 7)),
            ('star40', star_profile(rng, 40)),
            ('vase', vase_profile(rng, 30)),
            ('vase_tips', vase_profile(rng, 25, flat_ends=False)),
            ('glass', glass_profile(rng, 12)),
            ('glass_smooth', glass_profile(rng, 60)),
            ('ring', ring_profile()),
            ('cone', cone_profile())]


def segment_points(prof):
    """``(start, end)``, each ``(m, 2)``: the segments of a test profile in
    the form of :func:`lathe_shape.kernels.polyline.build_polyline_data`."""
    r0, z0, r1, z1 = prof
    return np.stack([r0, z0], axis=1), np.stack([r1, z1], axis=1)


def bounds(prof):
    """``(r_max, z_min, z_max, scale)`` of a profile."""
    r0, z0, r1, z1 = prof
    r_max = max(r0.max(), r1.max())
    z_min, z_max = min(z0.min(), z1.min()), max(z0.max(), z1.max())
    return r_max, z_min, z_max, max(r_max, z_max - z_min)


def random_rays(rng, prof, n):
    """Mixed rays ``(o, d)`` (float64, ``d`` not unit) around a profile.

    Kinds, in equal shares: from outside (near and far) aimed at points near
    the object; from inside the bounding cylinder in random directions;
    parallel to the axis; perpendicular to the axis; through the axis; aimed
    exactly at profile vertices.
    """
    r_max, z_min, z_max, scale = bounds(prof)
    zc = 0.5 * (z_min + z_max)
    k = n // 6
    kinds = []

    def sphere(m):
        v = rng.normal(size=(m, 3))
        return v / np.linalg.norm(v, axis=1, keepdims=True)

    def near(m):
        return np.stack([rng.uniform(-1.1, 1.1, m) * r_max,
                         rng.uniform(-1.1, 1.1, m) * r_max,
                         rng.uniform(z_min - 0.1 * scale, z_max + 0.1 * scale,
                                     m)], axis=1)

    # Outside, aimed at the object (a few far away)
    dist = np.where(rng.uniform(size=k) < 0.2, 100.0, 3.0) * scale
    o = sphere(k) * dist[:, None] + [0, 0, zc]
    kinds.append((o, near(k) - o))
    # Inside the bounding cylinder
    kinds.append((near(k), sphere(k)))
    # Parallel to the axis
    o = near(k)
    o[:, 2] = np.where(rng.uniform(size=k) < 0.5, z_min, z_max) \
        + rng.uniform(-2, 2, k) * scale
    kinds.append((o, np.stack([np.zeros(k), np.zeros(k),
                               rng.choice([-1.0, 1.0], k)], axis=1)))
    # Perpendicular to the axis
    o = near(k)
    ph = rng.uniform(0, 2 * np.pi, k)
    kinds.append((o, np.stack([np.cos(ph), np.sin(ph), np.zeros(k)], axis=1)))
    # Through the axis
    o = sphere(k) * 3 * scale + [0, 0, zc]
    tgt = np.stack([np.zeros(k), np.zeros(k),
                    rng.uniform(z_min, z_max, k)], axis=1)
    kinds.append((o, tgt - o))
    # Aimed at profile vertices (the joints)
    m = n - 5 * k
    r0, z0, _, _ = prof
    i = rng.integers(0, len(r0), m)
    ph = rng.uniform(0, 2 * np.pi, m)
    tgt = np.stack([r0[i] * np.cos(ph), r0[i] * np.sin(ph), z0[i]], axis=1)
    o = sphere(m) * 3 * scale + [0, 0, zc]
    kinds.append((o, tgt - o))

    o = np.vstack([a for a, _ in kinds])
    d = np.vstack([b for _, b in kinds])
    d *= rng.uniform(0.1, 10.0, (len(d), 1))
    return o, d


def inside_profile(prof, p):
    """Whether 3D points ``p`` ``(n, 3)`` lie inside the closed lathe.

    Even-odd rule in the (r, z) plane with a test ray towards +r; segments
    on the axis (dropped from ``prof``) can never be crossed by it.
    """
    r0, z0, r1, z1 = prof
    p = np.asarray(p, dtype=np.float64)
    pr = np.hypot(p[:, 0], p[:, 1])[:, None]
    pz = p[:, 2][:, None]
    straddle = (z0[None] > pz) != (z1[None] > pz)
    with np.errstate(divide='ignore', invalid='ignore'):
        rc = r0[None] + (pz - z0[None]) * (r1 - r0)[None] / (z1 - z0)[None]
    return (np.sum(straddle & (rc > pr), axis=1) % 2) == 1


def bspline_curve(name: str) -> tuple[np.ndarray, np.ndarray]:
    """``(segment controls, power coefficients)`` of the test curve ``name``
    (a key of :data:`BSPLINE_CURVES`), oriented clockwise."""
    seg = bs.bspline_segments(bs.orient_clockwise(BSPLINE_CURVES[name]))
    return seg, bs.power_coefficients(seg)


def bspline_rays(kind: str, seg: np.ndarray, rng: np.random.Generator, n: int):
    """``n`` rays ``(origin, direction)`` of one kind around the curve ``seg``:
    ``outside`` (aimed near the surface from 6 units away, non-unit
    directions), ``inside`` (from the bounding box), ``horizontal``,
    ``near_horizontal`` or ``vertical``."""
    T = rng.uniform(0, len(seg), n)
    i = np.minimum(T.astype(int), len(seg) - 1)
    r, z = bs.evaluate(seg, i, T - i)
    phi = rng.uniform(0, 2 * np.pi, n)
    on_curve = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)
    lo = seg.reshape(-1, 2).min(axis=0)
    hi = seg.reshape(-1, 2).max(axis=0)
    if kind == "outside":
        tgt = on_curve + rng.normal(scale=0.1, size=(n, 3))
        d = rng.normal(size=(n, 3))
        d /= np.linalg.norm(d, axis=1)[:, None]
        org = tgt - 6 * d
        d *= rng.uniform(0.3, 3.0, (n, 1))  # not unit length
    elif kind == "inside":
        org = np.stack([rng.uniform(-hi[0], hi[0], n), rng.uniform(-hi[0], hi[0], n),
                        rng.uniform(lo[1], hi[1], n)], axis=1)
        d = rng.normal(size=(n, 3))
    elif kind in ("horizontal", "near_horizontal"):
        tgt = on_curve + rng.normal(scale=0.05, size=(n, 3))
        a = rng.uniform(0, 2 * np.pi, n)
        dz = np.zeros(n)
        if kind == "near_horizontal":
            dz = rng.choice([1e-4, 1e-3, 1e-2, 3e-2], n) * rng.choice([-1, 1], n)
        d = np.stack([np.cos(a), np.sin(a), dz], axis=1)
        org = tgt - 5 * d
    elif kind == "vertical":
        org = np.stack([rng.uniform(-hi[0], hi[0], n), rng.uniform(-hi[0], hi[0], n),
                        np.full(n, lo[1] - 3.0)], axis=1)
        d = np.tile([0.0, 0.0, 1.0], (n, 1)) * rng.choice([1, -1], (n, 1))
        org[d[:, 2] < 0, 2] = hi[1] + 3.0
    else:
        raise ValueError(f"bspline_rays(): unknown ray kind '{kind}'")
    return org, d
