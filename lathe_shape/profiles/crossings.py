"""Which edges of a polygonal chain touch or cross each other (numpy only).

The one segment-intersection routine of the profile checks: the polyline
profile's simplicity test (:mod:`.polyline`) and the B-spline curve's
self-intersection test on the flattened curve (:mod:`.bspline`) both call
:func:`first_crossing`.

The edges of a chain of points ``q_0 .. q_(n-1)`` are ``q_k -> q_(k+1)``,
plus the closing edge ``q_(n-1) -> q_0`` when the chain is closed. Two
adjacent edges share a vertex by construction and are never reported here
(a fold back onto the previous edge is the caller's own test).

Method. A bounding-box hierarchy over the *chain order*: node ``k`` of level
``L`` bounds the edges ``k 2^L .. (k+1) 2^L - 1``, which lie close together
because consecutive edges of a curve do. The hierarchy is traversed against
itself one level at a time, keeping only the node pairs whose boxes overlap,
so that the exact orientation tests run on nearby edge pairs only: time and
memory grow like ``n log n`` for a curve whose distant parts do not overlap
in their boxes (every sane profile). Node pairs are expanded in chunks of
bounded size, depth first, lowest edge indices first, so that memory stays
bounded whatever the input; once a touching pair is found, pairs that cannot
give a lower one are dropped, so a self-intersecting chain is refused early.
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
    a = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    b = np.roll(a, -1, axis=0) if closed else a[1:]
    a = a[: len(b)]
    m = len(a)
    if m < 3:
        return None
    levels = _box_levels(a, b, tol)
    best = m * m  # code i * m + j of the lowest touching pair found (m * m: none)
    top = len(levels) - 1
    stack = [(top, np.zeros(1, dtype=np.int64), np.zeros(1, dtype=np.int64))]
    while stack:
        level, first, second = stack.pop()
        if level == 0:
            best = min(best, _lowest_touching(a, b, first, second, closed, tol, best))
            continue
        first, second = _overlapping_children(levels, level, first, second, m, best)
        # Chunks, the lowest edge indices on top of the stack (depth first).
        for start in range((len(first) - 1) // _CHUNK * _CHUNK, -1, -_CHUNK):
            stack.append((level - 1, first[start:start + _CHUNK], second[start:start + _CHUNK]))
    return None if best == m * m else (best // m, best % m)


def _box_levels(a: np.ndarray, b: np.ndarray, pad: float) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per level, the (lo, hi) corners of every node's box: level 0 the
    edges (grown by ``pad``), level ``L + 1`` the union of node pairs of
    level ``L``, up to a single root."""
    lo, hi = np.minimum(a, b) - pad, np.maximum(a, b) + pad
    levels = [(lo, hi)]
    while len(lo) > 1:
        if len(lo) % 2:  # an odd last node is its own parent
            lo, hi = np.concatenate([lo, lo[-1:]]), np.concatenate([hi, hi[-1:]])
        lo = np.minimum(lo[0::2], lo[1::2])
        hi = np.maximum(hi[0::2], hi[1::2])
        levels.append((lo, hi))
    return levels


def _overlapping_children(
    levels: list[tuple[np.ndarray, np.ndarray]],
    level: int,
    first: np.ndarray,
    second: np.ndarray,
    m: int,
    best: int,
) -> tuple[np.ndarray, np.ndarray]:
    """The child node pairs (one level down) of the node pairs ``first[k] <=
    second[k]`` whose boxes overlap and that could still hold a pair of
    edges lower than ``best``; sorted by their lowest possible pair."""
    lo, hi = levels[level - 1]
    count = len(lo)
    ca = (2 * first[:, None] + np.array([0, 0, 1, 1])).ravel()
    cb = (2 * second[:, None] + np.array([0, 1, 0, 1])).ravel()
    keep = (ca <= cb) & (cb < count)
    ca, cb = ca[keep], cb[keep]
    other = ca != cb  # a node always overlaps itself
    overlap = np.all((lo[ca] <= hi[cb]) & (lo[cb] <= hi[ca]), axis=1)
    shift = level - 1
    lowest = (ca << shift) * m + (cb << shift)  # no pair of edges below this
    keep = (~other | overlap) & (lowest < best)
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
    len_r, len_s = np.hypot(r[:, 0], r[:, 1]), np.hypot(s[:, 0], s[:, 1])
    # Orientation tests; d / |r| is the signed distance from the line of r.
    d1, d2 = _cross(r, q0 - p0), _cross(r, q1 - p0)
    d3, d4 = _cross(s, p0 - q0), _cross(s, p1 - q0)
    e_r, e_s = tol * len_r, tol * len_s
    straddle = (((d1 > e_r) & (d2 < -e_r)) | ((d1 < -e_r) & (d2 > e_r))) & (
        ((d3 > e_s) & (d4 < -e_s)) | ((d3 < -e_s) & (d4 > e_s))
    )

    def near(d: np.ndarray, e: np.ndarray, start: np.ndarray, vec: np.ndarray, length: np.ndarray,
             point: np.ndarray) -> np.ndarray:
        # Within tol of the line, and its projection within tol of the segment.
        along = _dot(point - start, vec)
        return (np.abs(d) <= e) & (along >= -e) & (along <= length * length + e)

    return (
        straddle
        | near(d1, e_r, p0, r, len_r, q0)
        | near(d2, e_r, p0, r, len_r, q1)
        | near(d3, e_s, q0, s, len_s, p0)
        | near(d4, e_s, q0, s, len_s, p1)
    )


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
