"""Small loops of a POV-Ray lathe curve, cut off (numpy only).

POV-Ray renders a lathe whose curve crosses itself: it only solves for
where rays meet the surface. The exact kernel of this project needs a
simple curve (its inside/outside parity, its checks). A repeated control
point of a ``cubic_spline`` or ``quadratic_spline`` (``objects/lathe2.pov``
does this) makes a segment that starts and ends at the same point: a small
loop, seen by POV-Ray as a small bulge, mostly hidden inside the rest of
the surface. :func:`remove_small_loops` cuts such loops off where the curve
crosses itself: the curve before the crossing joins the curve after it, the
cut pieces written exactly as Bezier segments (de Casteljau). What remains
is the same surface as POV-Ray's without the loop; the loop itself, a
closed curve, is returned too, to be revolved as a second solid. A loop larger than
:data:`MAX_LOOP_FRACTION` of the profile's size is left alone (the caller
refuses the curve, as before).
"""

from __future__ import annotations

import numpy as np

from .crossings import first_crossing, meeting_parameters, touch_tolerance
from .spline_kinds import bezier_points, kind_coefficients

__all__ = ["MAX_LOOP_FRACTION", "remove_small_loops"]

#: Largest loop cut off, as a fraction of the profile's size.
MAX_LOOP_FRACTION = 0.1

_SAMPLES = 64


def _evaluate(seg: np.ndarray, t: np.ndarray) -> np.ndarray:
    s = 1.0 - t
    w = np.stack([s**3, 3 * s * s * t, 3 * s * t * t, t**3], axis=-1)
    return np.einsum("...k,...kc->...c", w, seg)


def _split(seg: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
    """The two Bezier halves of a cubic Bezier segment at ``t``."""
    a, b, c, d = seg
    ab, bc, cd = a + t * (b - a), b + t * (c - b), c + t * (d - c)
    abc, bcd = ab + t * (bc - ab), bc + t * (cd - bc)
    m = abc + t * (bcd - abc)
    return np.array([a, ab, abc, m]), np.array([m, bcd, cd, d])


def _at(segs: np.ndarray, T: float) -> np.ndarray:
    k = min(int(T), len(segs) - 1)
    return _evaluate(segs[k], np.array(T - k))


def remove_small_loops(kind: str, points: np.ndarray,
                       source: str) -> tuple[str, np.ndarray, list[str], list[np.ndarray]]:
    """``(kind, points, notes, loops)``: the curve with its small
    self-crossing loops cut off (module docstring), as ``bezier`` points
    when anything was cut (else unchanged, no notes), and each loop cut off
    as the ``bezier`` points of a closed curve (revolved, the loops and the
    rest together are POV-Ray's surface). Polylines lose repeated
    consecutive points; sor curves (a radius per height) cannot loop."""
    p = np.asarray(points, dtype=np.float64)
    if kind == "sor":
        return kind, p, [], []
    if kind == "polyline":
        keep = np.concatenate([[True], np.any(p[1:] != p[:-1], axis=1)])
        if keep.all():
            return kind, p, [], []
        return kind, p[keep], [f"{int((~keep).sum())} repeated point(s) dropped"], []
    segs = bezier_points(kind_coefficients(kind, p, source)).reshape(-1, 4, 2)
    size = float(np.ptp(segs.reshape(-1, 2), axis=0).max()) or 1.0
    notes: list[str] = []
    loops: list[np.ndarray] = []
    for _ in range(16):
        t = np.arange(_SAMPLES) / _SAMPLES
        s, tt = 1.0 - t, t
        w = np.stack([s**3, 3 * s * s * tt, 3 * s * tt * tt, tt**3], axis=1)  # (samples, 4)
        pts = np.einsum("mk,nkc->nmc", w, segs).reshape(-1, 2)
        pts = np.concatenate([pts, segs[-1, 3][None]])
        closed = bool(np.allclose(pts[0], pts[-1], rtol=0, atol=1e-12 * size))
        chain = pts[:-1] if closed else pts
        pair = first_crossing(chain, closed, touch_tolerance(chain))
        if pair is None:
            break
        i, j = pair
        if closed and j == len(chain) - 1:
            break  # a crossing with the closing edge: leave it to the caller
        u, v = meeting_parameters(chain[i], chain[i + 1], chain[j], chain[j + 1])
        T1, T2 = (i + u) / _SAMPLES, (j + v) / _SAMPLES
        T1, T2 = _refine(segs, T1, T2)
        extent = float(np.ptp(pts[i:j + 2], axis=0).max())
        if extent > MAX_LOOP_FRACTION * size or T2 <= T1:
            break
        loops.append(_loop(segs, T1, T2).reshape(-1, 2))
        segs = _cut(segs, T1, T2)
        notes.append(f"the curve crosses itself near t={T1:.4g} and t={T2:.4g}, making a loop "
                     f"{extent:.3g} across ({100 * extent / size:.2g}% of the profile): the loop is "
                     f"written as a closed curve of its own, the rest as a bezier profile (together "
                     f"the surface POV-Ray renders)")
    if not notes:
        return kind, p, [], []
    return "bezier", segs.reshape(-1, 2), notes, loops


def _refine(segs: np.ndarray, T1: float, T2: float) -> tuple[float, float]:
    """The crossing parameters, exact where the crossing is a repeated
    point at segment ends (the usual loop), else by Newton's method."""
    n = len(segs)
    r1, r2 = round(T1), round(T2)
    if abs(T1 - r1) < 0.05 and abs(T2 - r2) < 0.05 and r1 < r2:
        a, b = _at(segs, float(r1)), _at(segs, float(r2))
        if np.allclose(a, b, rtol=0, atol=1e-9 * (1 + np.abs(a).max())):
            return float(r1), float(r2)
    best = (T1, T2)
    for _ in range(20):
        k1, k2 = min(int(T1), n - 1), min(int(T2), n - 1)
        f = _at(segs, T1) - _at(segs, T2)
        d1 = _derivative(segs[k1], T1 - k1)
        d2 = _derivative(segs[k2], T2 - k2)
        jac = np.column_stack([d1, -d2])
        if abs(np.linalg.det(jac)) < 1e-300:
            break
        step = np.linalg.solve(jac, -f)
        T1, T2 = T1 + step[0], T2 + step[1]
        if not (0 <= T1 <= n and 0 <= T2 <= n):
            return best
        if np.abs(step).max() < 1e-14:
            break
    return T1, T2


def _derivative(seg: np.ndarray, t: float) -> np.ndarray:
    s = 1.0 - t
    return 3 * (s * s * (seg[1] - seg[0]) + 2 * s * t * (seg[2] - seg[1]) + t * t * (seg[3] - seg[2]))


def _loop(segs: np.ndarray, T1: float, T2: float) -> np.ndarray:
    """The part of the curve between ``T1`` and ``T2``, closed (Bezier
    segments)."""
    n = len(segs)
    k1, k2 = min(int(T1), n - 1), min(int(T2), n - 1)
    t1, t2 = T1 - k1, T2 - k2
    if k1 == k2:
        piece = _split(_split(segs[k1], t1)[1], (t2 - t1) / (1 - t1))[0] if t1 < 1 else segs[k1]
        parts = [piece]
    else:
        parts = []
        if t1 < 1 - 1e-9:
            parts.append(_split(segs[k1], t1)[1])
        parts += list(segs[k1 + 1:k2])
        if t2 > 1e-9:
            parts.append(_split(segs[k2], t2)[0])
    parts = [q.copy() for q in parts]
    for a, b in zip(parts[:-1], parts[1:], strict=False):
        b[0] = a[3]
    parts[-1][3] = parts[0][0]
    return np.array(parts)


def _cut(segs: np.ndarray, T1: float, T2: float) -> np.ndarray:
    """The curve without its part between ``T1`` and ``T2``."""
    n = len(segs)
    k1, k2 = min(int(T1), n - 1), min(int(T2), n - 1)
    t1, t2 = T1 - k1, T2 - k2
    before = list(segs[:k1])
    after = list(segs[k2 + 1:])
    eps = 1e-9
    if t1 > eps:
        before.append(_split(segs[k1], t1)[0])
    if t2 < 1 - eps:
        after.insert(0, _split(segs[k2], t2)[1])
    if before and after:
        join = 0.5 * (before[-1][3] + after[0][0])
        before[-1] = before[-1].copy()
        after[0] = after[0].copy()
        before[-1][3] = after[0][0] = join
    return np.array(before + after)
