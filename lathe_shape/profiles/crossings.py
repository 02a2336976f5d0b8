"""Which edges of a polygonal chain touch or cross each other (numpy only).

The one segment-intersection routine of the profile checks: the polyline
profile's simplicity test (:mod:`.polyline`) and the B-spline curve's
self-intersection test on the flattened curve (:mod:`.bspline`) both call
:func:`first_crossing`.

The edges of a chain of points ``q_0 .. q_(n-1)`` are ``q_k -> q_(k+1)``,
plus the closing edge ``q_(n-1) -> q_0`` when the chain is closed. Two
adjacent edges share a vertex by construction and are never reported here
(a fold back onto the previous edge is the caller's own test).

Method. A hierarchy of boxes over the *chain order*: node ``k`` of level
``L`` bounds the edges ``k 2^L .. (k+1) 2^L - 1``, which lie close together
because consecutive edges of a curve do. Each box is aligned with its node's
chord, so that a run of nearly straight edges, or a comb of long thin teeth
at any angle, gets a thin box. The hierarchy is traversed against itself one
level at a time, keeping only the node pairs whose boxes overlap (separating
axis test), so that the exact orientation tests run on nearby edge pairs
only: time and memory grow like ``n log n`` when far-apart parts of the
curve have disjoint boxes (every sane profile; time grows with the number of
overlapping box pairs otherwise). Node pairs are expanded in chunks of
bounded size, depth first, lowest edge indices first, so that memory stays
bounded whatever the input; once a touching pair is found, node pairs that
cannot hold a lower one are dropped, so a self-intersecting chain is refused
early and the pair reported is the lowest.
"""

from __future__ import annotations

import numpy as np

__all__ = ["first_crossing", "meeting_parameters", "touch_tolerance"]

#: Node pairs expanded at a time (bounds the memory of the traversal).
_CHUNK = 1 << 16

#: Distances below this fraction of the profile's size count as touching.
_RELATIVE_TOUCH = 1e-12


def touch_tolerance(points: np.ndarray) -> float:
    """The distance below which two parts of a profile count as touching:
    ``1e-12`` of the profile's size (the larger side of its bounding box),
    but not below the rounding of its coordinates. Both scale with the
    profile, so a scaled copy is accepted or refused alike."""
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    extent = float(np.max(pts.max(axis=0) - pts.min(axis=0)))
    rounding = 16.0 * np.finfo(np.float64).eps * float(np.abs(pts).max())
    return _RELATIVE_TOUCH * extent + rounding


def first_crossing(points: np.ndarray, closed: bool, tol: float) -> tuple[int, int] | None:
    """The lowest pair ``(i, j)``, ``i < j``, of non-adjacent edges of the
    chain ``points`` (array of shape (n, 2)) that cross or come within
    ``tol`` of each other, or None when the chain is simple.

    Edge ``k`` runs from ``points[k]`` to ``points[k + 1]``; a ``closed``
    chain also has the edge ``n - 1`` from ``points[n - 1]`` back to
    ``points[0]``.
    """
    chain = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    if closed:
        chain = np.concatenate([chain, chain[:1]])
    a, b = chain[:-1], chain[1:]
    m = len(a)
    if m < 3:
        return None
    # Levels 0 (the edges) .. top (a single node holding every edge).
    top = max(1, (m - 1).bit_length())
    levels = [_Boxes.of_nodes(chain, 1 << level, tol) for level in range(top + 1)]
    best = m * m  # code i * m + j of the lowest touching pair found (m * m: none)
    stack = [(top, np.zeros(1, dtype=np.int64), np.zeros(1, dtype=np.int64))]
    while stack:
        level, first, second = stack.pop()
        if level == 0:
            best = min(best, _lowest_touching(a, b, first, second, closed, tol, best))
            continue
        first, second = _overlapping_children(levels[level - 1], level - 1, first, second, m, best)
        # Chunks, the lowest edge indices on top of the stack (depth first).
        for start in range((len(first) - 1) // _CHUNK * _CHUNK, -1, -_CHUNK):
            stack.append((level - 1, first[start:start + _CHUNK], second[start:start + _CHUNK]))
    return None if best == m * m else (best // m, best % m)


class _Boxes:
    """Oriented boxes of the nodes of one level: node ``k`` holds the chain
    points ``k size .. (k+1) size`` (its edges). Each box is aligned with its
    node's chord (first to last point), so that a run of nearly parallel
    edges, or a comb of long thin teeth at any angle, gets a thin box;
    ``center + s axis + t normal`` for ``|s| <= half_length``,
    ``|t| <= half_width``."""

    def __init__(self, center: np.ndarray, axis: np.ndarray, half: np.ndarray) -> None:
        self.center, self.axis, self.half = center, axis, half

    @classmethod
    def of_nodes(cls, chain: np.ndarray, size: int, pad: float) -> _Boxes:
        last = len(chain) - 1
        count = -(-last // size)
        index = np.minimum(np.arange(count)[:, None] * size + np.arange(size + 1), last)
        pts = chain[index]  # (count, size + 1, 2)
        chord = pts[:, -1] - pts[:, 0]
        length = np.hypot(chord[:, 0], chord[:, 1])
        closed_node = length == 0.0  # a whole loop: fall back to the r, z axes
        axis = np.where(closed_node[:, None], [1.0, 0.0], chord / np.where(closed_node, 1.0, length)[:, None])
        normal = np.stack([-axis[:, 1], axis[:, 0]], axis=1)
        s = np.einsum("kpi,ki->kp", pts, axis)
        t = np.einsum("kpi,ki->kp", pts, normal)
        s_lo, s_hi, t_lo, t_hi = s.min(axis=1), s.max(axis=1), t.min(axis=1), t.max(axis=1)
        center = 0.5 * ((s_lo + s_hi)[:, None] * axis + (t_lo + t_hi)[:, None] * normal)
        half = 0.5 * np.stack([s_hi - s_lo, t_hi - t_lo], axis=1) + pad
        return cls(center, axis, half)

    def overlap(self, i: np.ndarray, j: np.ndarray) -> np.ndarray:
        """Whether boxes ``i[k]`` and ``j[k]`` overlap: no separating axis
        among the four box axes (separating axis theorem)."""
        d = self.center[j] - self.center[i]
        ua, ub = self.axis[i], self.axis[j]
        va, vb = np.stack([-ua[:, 1], ua[:, 0]], 1), np.stack([-ub[:, 1], ub[:, 0]], 1)
        ha, hb = self.half[i], self.half[j]
        apart = np.zeros(len(i), dtype=bool)
        for w in (ua, va, ub, vb):
            reach = (ha[:, 0] * np.abs(_dot(ua, w)) + ha[:, 1] * np.abs(_dot(va, w))
                     + hb[:, 0] * np.abs(_dot(ub, w)) + hb[:, 1] * np.abs(_dot(vb, w)))
            apart |= np.abs(_dot(d, w)) > reach
        return ~apart


def _overlapping_children(
    boxes: _Boxes, level: int, first: np.ndarray, second: np.ndarray, m: int, best: int
) -> tuple[np.ndarray, np.ndarray]:
    """The child node pairs (at ``level``, with ``boxes``) of the node pairs
    ``first[k] <= second[k]`` one level up whose boxes overlap and that could
    still hold a pair of edges lower than ``best``; sorted by their lowest
    possible pair."""
    count = len(boxes.center)
    ca = (2 * first[:, None] + np.array([0, 0, 1, 1])).ravel()
    cb = (2 * second[:, None] + np.array([0, 1, 0, 1])).ravel()
    keep = (ca <= cb) & (cb < count)
    ca, cb = ca[keep], cb[keep]
    lowest = (ca << level) * m + (cb << level)  # no pair of edges below this
    keep = lowest < best
    ca, cb, lowest = ca[keep], cb[keep], lowest[keep]
    keep = (ca == cb) | boxes.overlap(ca, cb)  # a node always overlaps itself
    order = np.argsort(lowest[keep], kind="stable")
    return ca[keep][order], cb[keep][order]


def _lowest_touching(
    a: np.ndarray, b: np.ndarray, i: np.ndarray, j: np.ndarray, closed: bool, tol: float, best: int
) -> int:
    """Code ``i * m + j`` of the lowest touching pair among the edge pairs
    ``(i, j)`` (``i <= j``), or ``best`` when none is lower."""
    m = len(a)
    nonadjacent = (j > i + 1) & ~(closed & (i == 0) & (j == m - 1))
    i, j = i[nonadjacent], j[nonadjacent]
    if len(i) == 0:
        return best
    hit = _touching(a[i], b[i], a[j], b[j], tol)
    if not hit.any():
        return best
    return min(best, int(np.min(i[hit] * m + j[hit])))


def _cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return u[..., 0] * v[..., 1] - u[..., 1] * v[..., 0]


def _dot(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return u[..., 0] * v[..., 0] + u[..., 1] * v[..., 1]


def _touching(p0: np.ndarray, p1: np.ndarray, q0: np.ndarray, q1: np.ndarray, tol: float) -> np.ndarray:
    """Whether segments ``p0 -> p1`` and ``q0 -> q1`` cross or come within
    ``tol`` of each other: a proper crossing (each segment's ends strictly on
    both sides of the other's line), or an end point within ``tol`` of the
    other segment (touching, or overlapping collinear segments)."""
    r, s = p1 - p0, q1 - q0
    # Orientation tests; d / |r| is the signed distance from the line of r.
    d1, d2 = _cross(r, q0 - p0), _cross(r, q1 - p0)
    d3, d4 = _cross(s, p0 - q0), _cross(s, p1 - q0)
    e_r = tol * np.hypot(r[:, 0], r[:, 1])
    e_s = tol * np.hypot(s[:, 0], s[:, 1])
    straddle = (((d1 > e_r) & (d2 < -e_r)) | ((d1 < -e_r) & (d2 > e_r))) & (
        ((d3 > e_s) & (d4 < -e_s)) | ((d3 < -e_s) & (d4 > e_s))
    )
    return (
        straddle
        | (_distance_to_segment(q0, p0, r) <= tol)
        | (_distance_to_segment(q1, p0, r) <= tol)
        | (_distance_to_segment(p0, q0, s) <= tol)
        | (_distance_to_segment(p1, q0, s) <= tol)
    )


def _distance_to_segment(point: np.ndarray, start: np.ndarray, vec: np.ndarray) -> np.ndarray:
    """Distance from ``point`` to the segment ``start -> start + vec`` (a
    point when ``vec`` is zero)."""
    length_sq = _dot(vec, vec)
    along = _dot(point - start, vec) / np.where(length_sq > 0.0, length_sq, 1.0)
    offset = start + np.clip(along, 0.0, 1.0)[:, None] * vec - point
    return np.hypot(offset[:, 0], offset[:, 1])


def meeting_parameters(p0: np.ndarray, p1: np.ndarray, q0: np.ndarray, q1: np.ndarray) -> tuple[float, float]:
    """Where two touching segments meet: the parameters ``(u, v)`` in [0, 1]
    of the meeting point ``p0 + u (p1 - p0)`` ~ ``q0 + v (q1 - q0)`` (for
    error messages; parallel segments give the point of ``p`` nearest ``q``)."""
    r, s, qp = p1 - p0, q1 - q0, q0 - p0
    den = float(_cross(r, s))
    if abs(den) > 1e-9 * float(np.hypot(*r) * np.hypot(*s)):
        u, v = float(_cross(qp, s)) / den, float(_cross(qp, r)) / den
    else:
        u = float(_dot(qp, r)) / max(float(_dot(r, r)), np.finfo(float).tiny)
        u = min(max(u, 0.0), 1.0)
        v = float(_dot(p0 + u * r - q0, s)) / max(float(_dot(s, s)), np.finfo(float).tiny)
    return min(max(u, 0.0), 1.0), min(max(v, 0.0), 1.0)
