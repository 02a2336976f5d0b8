"""Where to put a polyline's points on a curve: the placement rules and the
error proxy of the paper's open problems (docs/method.md, end), used by
``scripts/open_problems.py``.

A curve is given densely (thousands of points); a polyline is a subset of
those points, given by their indices. Where a polyline with smooth shading is
wrong, the normal is wrong by about the turning angle ``dtheta`` of a piece,
over a strip as long as the piece ``L``; the image error then behaves like
the proxy ``E = sum_i L_i dtheta_i^2 = sum_i kappa_i^2 L_i^3`` (kappa =
curvature). Minimising it for a fixed number of pieces equidistributes it:
``L_i ~ kappa^(-2/3)``, i.e. points at equal steps of ``int kappa^(2/3) ds``.
"""

from __future__ import annotations

import os

import numpy as np

from ..profiles import bspline as bs
from ..profiles import build_from_spec, spec_with_step

__all__ = [
    "dense_arcs",
    "dense_bspline",
    "error_report",
    "nearest_indices",
    "plot_errors",
    "proxy",
    "rule_greedy",
    "rule_k23",
    "rule_uniform",
    "turning",
]

#: Per object: rule -> [(segments, image error, proxy E), ...].
ErrorTable = dict[str, list[tuple[int, float, float]]]


def dense_bspline(controls: np.ndarray, per_segment: int = 512) -> tuple[np.ndarray, np.ndarray]:
    """Dense points of an open B-spline curve (``per_segment`` per segment)
    and the indices of the segment joints."""
    seg = bs.bspline_segments(controls, "glass")
    T = np.linspace(0.0, len(seg), len(seg) * per_segment + 1)
    i = np.minimum(T.astype(int), len(seg) - 1)
    r, z = bs.evaluate(seg, i, T - i)
    pts = np.stack([r, z], axis=1)
    pts[0, 0] = pts[-1, 0] = 0.0
    return pts, np.arange(0, len(T), per_segment)


def dense_arcs(spec: dict, max_chord: float = 0.02) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Dense points of an arc object (arcs at 0.5 degrees, lines cut into
    pieces <= max_chord), sharp flags, and the indices of the arc joints."""
    pts, sharp = build_from_spec(spec_with_step(spec, 0.5))
    out, flags = [pts[0]], [sharp[0]]
    for a, b, s in zip(pts[:-1], pts[1:], sharp[1:], strict=True):
        n = max(1, int(np.ceil(np.linalg.norm(b - a) / max_chord)))
        for k in range(1, n + 1):
            out.append(a + (b - a) * k / n)
            flags.append(bool(s) if k == n else False)
    dense = np.array(out)
    dense[np.abs(dense[:, 0]) < 1e-9, 0] = 0.0  # round-off on the axis
    # Joints: the vertices of the coarse (paper) division.
    coarse, _ = build_from_spec(spec)
    return dense, np.array(flags), np.unique(nearest_indices(dense, coarse))


def nearest_indices(dense: np.ndarray, points: np.ndarray) -> np.ndarray:
    """For each point, the index of the nearest dense point."""
    return np.array([int(np.argmin(np.linalg.norm(dense - p, axis=1))) for p in points])


def turning(dense: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Cumulative arc length s and cumulative |turning angle| at the dense points."""
    d = np.diff(dense, axis=0)
    length = np.hypot(d[:, 0], d[:, 1])
    ang = np.arctan2(d[:, 1], d[:, 0])
    turn = np.abs(np.angle(np.exp(1j * np.diff(ang))))
    s = np.concatenate([[0.0], np.cumsum(length)])
    th = np.concatenate([[0.0, 0.0], np.cumsum(turn)])  # turn at interior vertex k -> th[k+1]
    return s, th


def proxy(idx: np.ndarray, s: np.ndarray, th: np.ndarray) -> float:
    """The error proxy E = sum_i L_i dtheta_i^2 of the polyline through dense
    points ``idx`` (turning inside each piece, joints excluded)."""
    L = np.diff(s[idx])
    dth = th[idx[1:]] - th[idx[:-1] + 1]
    return float(np.sum(L * np.maximum(dth, 0.0) ** 2))


def _by_measure(measure: np.ndarray, n_seg: int, must: np.ndarray) -> np.ndarray:
    """Dense indices at equal steps of a cumulative measure (plus ``must``)."""
    target = np.linspace(0.0, measure[-1], n_seg + 1)
    idx = np.searchsorted(measure, target).clip(0, len(measure) - 1)
    return np.unique(np.concatenate([idx, must, [0, len(measure) - 1]]))


def rule_uniform(s: np.ndarray, n_seg: int, must: np.ndarray) -> np.ndarray:
    """Equal steps of arc length (no care)."""
    return _by_measure(s, n_seg, must)


def rule_k23(s: np.ndarray, th: np.ndarray, n_seg: int, must: np.ndarray) -> np.ndarray:
    """Equal steps of int kappa^(2/3) ds (the E-optimal density), with a 2%
    arc-length share so straight pieces still get points."""
    ds = np.diff(s)
    dth = np.diff(th)[: len(ds)]
    kappa = np.where(ds > 0, dth / np.maximum(ds, 1e-300), 0.0)
    w = kappa ** (2.0 / 3.0) * ds
    w = w + 0.02 * w.sum() / s[-1] * ds
    return _by_measure(np.concatenate([[0.0], np.cumsum(w)]), n_seg, must)


def rule_greedy(s: np.ndarray, th: np.ndarray, n_seg: int, start: np.ndarray) -> np.ndarray:
    """Start from ``start`` (the curve's joints) and halve (in arc length) the
    piece with the largest L dtheta^2 until there are n_seg pieces."""
    idx = sorted(set(int(i) for i in start))
    while len(idx) - 1 < n_seg:
        a = np.array(idx)
        L = np.diff(s[a])
        dth = np.maximum(th[a[1:]] - th[a[:-1] + 1], 0.0)
        cost = L * dth ** 2 + 1e-12 * L  # straight pieces: split the longest last
        for k in np.argsort(-cost):
            mid = int(np.searchsorted(s, 0.5 * (s[a[k]] + s[a[k + 1]])))
            if a[k] < mid < a[k + 1]:
                idx.append(mid)
                idx.sort()
                break
        else:
            break
    return np.array(idx)


def _segments_to_reach(rows: list[tuple[int, float, float]], target: float) -> str:
    """Segments at which a rule's error reaches ``target`` (log-log
    interpolation between the rendered counts)."""
    ns = np.array([r[0] for r in rows], float)
    es = np.array([r[1] for r in rows], float)
    order = np.argsort(ns)
    ns, es = ns[order], es[order]
    below = np.flatnonzero(es <= target)
    if len(below) == 0:
        return f">{int(ns[-1])}"
    k = below[0]
    if k == 0:
        return f"<={int(ns[0])}"
    x0, x1, y0, y1 = np.log(ns[k - 1]), np.log(ns[k]), np.log(es[k - 1]), np.log(es[k])
    x = x0 + (np.log(target) - y0) * (x1 - x0) / (y1 - y0) if y1 != y0 else x1
    return f"{np.exp(x):.0f}"


def error_report(results: dict[str, ErrorTable], reference_count: int = 31) -> list[str]:
    """The tables: error and proxy per rule and count, the proxy's rank
    correlation with the image error, and the segments each rule needs to
    reach the error of the uniform polyline with ``reference_count``."""
    lines: list[str] = []
    all_err, all_proxy = [], []
    for obj, table in results.items():
        lines.append(f"\n{obj}: relative mean abs image error vs segments (proxy E = sum L dtheta^2)")
        for rule, rows in table.items():
            lines.append(f"  {rule:<10}" + "".join(f"  N={n:<4d}{e:.4f} (E {p:.2g})" for n, e, p in rows))
            all_err += [e for _, e, _ in rows]
            all_proxy += [p for _, _, p in rows]
    rho = float(np.corrcoef(np.argsort(np.argsort(all_err)), np.argsort(np.argsort(all_proxy)))[0, 1])
    lines.append(f"\nproxy check: Spearman rank correlation of E with the image error over "
                 f"{len(all_err)} renders: {rho:.3f}")
    lines.append("\nsegments needed to reach the image error of the uniform polyline with the "
                 "reference count (log-log interpolation):")
    for obj, table in results.items():
        ref_n = min(table["uniform"], key=lambda r: abs(r[0] - reference_count))
        parts = [f"{rule} {_segments_to_reach(rows, ref_n[1])}" for rule, rows in table.items()]
        lines.append(f"  {obj}: uniform N={ref_n[0]} error {ref_n[1]:.4f} -> " + ", ".join(parts))
    return lines


def plot_errors(results: dict[str, ErrorTable], path: str | os.PathLike) -> None:
    """Error vs segments per object (log-log), one colour per rule."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import NullFormatter, ScalarFormatter

    rules = sorted({rule for table in results.values() for rule in table})
    colours = {rule: f"C{k}" for k, rule in enumerate(rules)}
    fig, axes = plt.subplots(1, len(results), figsize=(4.2 * len(results), 3.8))
    for ax, (obj, table) in zip(np.atleast_1d(axes), results.items(), strict=True):
        for rule, rows in table.items():
            rows = sorted(rows)
            ax.loglog([r[0] for r in rows], [r[1] for r in rows], "o-", ms=3, label=rule,
                      color=colours[rule])
        ax.set_title(obj, fontsize=9)
        ax.set_xlabel("polyline segments")
        ax.grid(True, which="both", alpha=0.3)
        # Ticks at the segment counts rendered (a few, to stay readable).
        ticks: list[int] = []
        for n in sorted({r[0] for rows in table.values() for r in rows}):
            if not ticks or n >= 1.15 * ticks[-1]:
                ticks.append(n)
        ax.set_xticks(ticks)
        ax.xaxis.set_major_formatter(ScalarFormatter())
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.legend(fontsize=8)
    np.atleast_1d(axes)[0].set_ylabel("relative mean abs image error")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
