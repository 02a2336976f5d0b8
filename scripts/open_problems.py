#!/usr/bin/env python3
"""The paper's two open problems (method.md, end), answered with data.

    python scripts/open_problems.py                 # 128x128, 16 spp
    python scripts/open_problems.py --quick         # 32x32, 2 spp, fewer counts (smoke run)
    python scripts/open_problems.py --out out/open --res 192 --spp 32

(a) *How does image quality depend on the number of segments?* For the fig.
8b glass (an exact B-spline) and the arc-built fig. 9 glass, fig. 10a cup and
fig. 10b bottle, polylines with N segments are placed on the exact curve by
several rules and rendered with ``lathe_path``; the image error is the
relative mean absolute difference to the exact object rendered with the
*same* seed and spp (the noise is correlated, so the difference is the
geometry's). Rules: ``uniform`` (equal steps of the spline parameter for the
B-spline, equal arc length for the arc objects: no care), ``adaptive``
(:func:`lathe_shape.profiles.bspline.to_polyline` ``'adaptive'``: equal turning angle),
``arc-equal`` (the arc objects' own arcs divided equally, method.md section
2.3), and the two rules of (b).

(b) *Which polyline is optimal for a given curve?* Where a polyline with
smooth shading is wrong, the normal is wrong by about the turning angle
``dtheta`` of the piece, over a strip as long as the piece ``L``; the image
error then behaves like ``E = sum_i L_i dtheta_i^2 = sum_i kappa_i^2 L_i^3``
(kappa = curvature). Minimising it for fixed N equidistributes it:
``L_i ~ kappa^(-2/3)``, i.e. points at equal steps of ``int kappa^(2/3) ds``
(rule ``kappa^2/3``); ``greedy`` starts from the curve's own joints and
repeatedly halves the piece with the largest ``L dtheta^2``. The proxy ``E``
is checked against the image error (rank correlation over all renders), and
the table lists the segments each rule needs to reach the image error of the
uniform polyline with 31 segments (fig. 8a's count).

Writes ``open_problems.png`` (error vs N per object, log-log),
``open_problems.txt`` (the tables) into ``--out``.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "scripts"))
sys.path.insert(0, str(ROOT))

import reproduce_paper as rp  # noqa: E402

# ---------------------------------------------------------------------------
# Dense exact curves and polylines as index subsets of them
# ---------------------------------------------------------------------------


def dense_bspline(per_segment: int = 512) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Dense points of the fig. 8b curve, their global parameter T, and the
    indices of the segment joints (T integer)."""
    from lathe_shape.profiles import bspline as B

    seg = B.bspline_segments(rp.GLASS_BSPLINE, "glass")
    T = np.linspace(0.0, len(seg), len(seg) * per_segment + 1)
    i = np.minimum(T.astype(int), len(seg) - 1)
    r, z = B.evaluate(seg, i, T - i)
    pts = np.stack([r, z], axis=1)
    pts[0, 0] = pts[-1, 0] = 0.0
    return pts, T, np.arange(0, len(T), per_segment)


def dense_arcs(spec: dict, max_chord: float = 0.02) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Dense points of an arc object (arcs at 0.5 degrees, lines cut into
    pieces <= max_chord), sharp flags, and the indices of the arc joints."""
    from lathe_shape.profiles.arcs import build_from_spec

    fine = rp.fine_spec(spec, 0.5)
    pts, sharp = build_from_spec(fine)
    # Joints: the vertices of the coarse (paper) division that are pieces' ends.
    out, flags = [pts[0]], [sharp[0]]
    for a, b, s in zip(pts[:-1], pts[1:], sharp[1:], strict=True):
        n = max(1, int(np.ceil(np.linalg.norm(b - a) / max_chord)))
        for k in range(1, n + 1):
            out.append(a + (b - a) * k / n)
            flags.append(bool(s) if k == n else False)
    dense = np.array(out)
    dense[np.abs(dense[:, 0]) < 1e-9, 0] = 0.0  # round-off on the axis
    coarse, _ = build_from_spec(spec)
    joints = [int(np.argmin(np.linalg.norm(dense - p, axis=1))) for p in coarse]
    return dense, np.array(flags), np.unique(joints)


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


def by_measure(measure: np.ndarray, n_seg: int, must: np.ndarray) -> np.ndarray:
    """Dense indices at equal steps of a cumulative measure (plus ``must``)."""
    target = np.linspace(0.0, measure[-1], n_seg + 1)
    idx = np.searchsorted(measure, target).clip(0, len(measure) - 1)
    return np.unique(np.concatenate([idx, must, [0, len(measure) - 1]]))


def rule_uniform(s: np.ndarray, n_seg: int, must: np.ndarray) -> np.ndarray:
    return by_measure(s, n_seg, must)


def rule_k23(s: np.ndarray, th: np.ndarray, n_seg: int, must: np.ndarray) -> np.ndarray:
    """Equal steps of int kappa^(2/3) ds (the E-optimal density), with a 2%
    arc-length share so straight pieces still get points."""
    ds = np.diff(s)
    dth = np.diff(th)[: len(ds)]
    kappa = np.where(ds > 0, dth / np.maximum(ds, 1e-300), 0.0)
    w = kappa ** (2.0 / 3.0) * ds
    w = w + 0.02 * w.sum() / s[-1] * ds
    return by_measure(np.concatenate([[0.0], np.cumsum(w)]), n_seg, must)


def rule_greedy(s: np.ndarray, th: np.ndarray, n_seg: int, start: np.ndarray) -> np.ndarray:
    """Start from ``start`` (the curve's joints) and halve (in arc length) the
    piece with the largest L dtheta^2 until there are n_seg pieces."""
    idx = sorted(set(int(i) for i in start))
    while len(idx) - 1 < n_seg:
        a = np.array(idx)
        L = np.diff(s[a])
        dth = np.maximum(th[a[1:]] - th[a[:-1] + 1], 0.0)
        cost = L * dth ** 2 + 1e-12 * L  # straight pieces: split the longest last
        order = np.argsort(-cost)
        for k in order:
            mid = int(np.searchsorted(s, 0.5 * (s[a[k]] + s[a[k + 1]])))
            if a[k] < mid < a[k + 1]:
                idx.append(mid)
                idx.sort()
                break
        else:
            break
    return np.array(idx)


# ---------------------------------------------------------------------------
# Rendering
# ---------------------------------------------------------------------------


def write_csv(folder: Path, name: str, pts: np.ndarray, sharp: np.ndarray | None = None) -> str:
    from lathe_shape.profiles.arcs import profile_to_csv

    sharp = np.zeros(len(pts), bool) if sharp is None else sharp
    path = folder / f"{name}.csv"
    path.write_text(profile_to_csv(pts, sharp))
    return str(path)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=ROOT / "out" / "open_problems")
    parser.add_argument("--quick", action="store_true", help="32x32, 2 spp, few counts")
    parser.add_argument("--res", type=int)
    parser.add_argument("--spp", type=int)
    parser.add_argument("--seed", type=int, default=3)
    parser.add_argument("--variant", default="llvm_ad_rgb")
    args = parser.parse_args(argv)
    import mitsuba as mi

    mi.set_variant(args.variant)
    import lathe_shape  # noqa: F401
    from lathe_shape.profiles import bspline as B
    from lathe_shape.profiles.arcs import build_from_spec

    res = args.res or (32 if args.quick else 128)
    spp = args.spp or (2 if args.quick else 16)
    counts = [16, 31, 64] if args.quick else [16, 24, 31, 42, 64, 96, 128, 192]
    steps = [15.0, 7.5] if args.quick else [30.0, 20.0, 15.0, 10.0, 7.5, 5.0, 3.0, 2.0]
    args.out.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix="open_problems_"))
    t_start = time.perf_counter()
    print(f"{res}x{res}, {spp} spp, seed {args.seed} (exact references use the same seed and spp)")

    def render(fig: str, filename: str) -> np.ndarray:
        return rp.render(rp.PAPER / f"{fig}.xml", res, spp, args.seed, filename=filename)[0]

    results: dict[str, dict[str, list[tuple[int, float, float]]]] = {}
    lines: list[str] = []

    # --- the B-spline glass ------------------------------------------------
    exact = rp.render(rp.PAPER / "fig8b.xml", res, spp, args.seed)[0]
    dense, _, joints = dense_bspline()
    s, th = turning(dense)
    seg = B.bspline_segments(rp.GLASS_BSPLINE, "glass")
    none = np.array([], dtype=int)
    table: dict[str, list[tuple[int, float, float]]] = {}
    for n in counts:
        polys = {
            "uniform": B.to_polyline(seg, n + 1, "uniform"),
            "adaptive": B.to_polyline(seg, n + 1, "adaptive"),
            "kappa^2/3": dense[rule_k23(s, th, n, none)],
            "greedy": dense[rule_greedy(s, th, n, joints)],
        }
        for rule, pts in polys.items():
            idx = np.array([int(np.argmin(np.linalg.norm(dense - p, axis=1))) for p in pts])
            image = render("fig8b", write_csv(tmp, f"glass_{rule.replace('^2/3', '23')}_{n}", pts))
            err, _ = rp.image_error(image, exact)
            table.setdefault(rule, []).append((len(pts) - 1, err, proxy(np.unique(idx), s, th)))
    results["glass (fig. 8b B-spline)"] = table

    # --- the arc objects -----------------------------------------------------
    for fig, name in (("fig9", "glass_fig9"), ("fig10a", "sundae_cup"), ("fig10b", "brandy_bottle")):
        spec = rp.SPECS[name]()
        exact = render(fig, f"{name}_fine.csv")
        dense, dflags, _ = dense_arcs(spec)
        s, th = turning(dense)
        must = np.flatnonzero(dflags)
        table = {}
        for step in steps:
            coarse = rp.fine_spec(spec, step)
            pts, sharp = build_from_spec(coarse)
            n = len(pts) - 1
            image = render(fig, write_csv(tmp, f"{name}_arc_{step:g}", pts, sharp))
            idx = np.unique([int(np.argmin(np.linalg.norm(dense - p, axis=1))) for p in pts])
            table.setdefault("arc-equal", []).append((n, rp.image_error(image, exact)[0], proxy(idx, s, th)))
            for rule, idx in (("uniform", rule_uniform(s, n, must)), ("kappa^2/3", rule_k23(s, th, n, must))):
                image = render(fig, write_csv(tmp, f"{name}_{rule.replace('^2/3', '23')}_{n}",
                                              dense[idx], dflags[idx]))
                table.setdefault(rule, []).append((len(idx) - 1, rp.image_error(image, exact)[0],
                                                   proxy(idx, s, th)))
        results[f"{name} (fig. {fig[3:]}, arcs)"] = table
        print(f"  {name} done ({time.perf_counter() - t_start:.0f} s)", flush=True)

    # --- tables ---------------------------------------------------------------
    all_err, all_proxy = [], []
    for obj, table in results.items():
        lines.append(f"\n{obj}: relative mean abs image error vs segments (proxy E = sum L dtheta^2)")
        for rule, rows in table.items():
            lines.append(f"  {rule:<10}" + "".join(f"  N={n:<4d}{e:.4f} (E {p:.2g})" for n, e, p in rows))
            all_err += [e for _, e, _ in rows]
            all_proxy += [p for _, _, p in rows]
    rank_e = np.argsort(np.argsort(all_err))
    rank_p = np.argsort(np.argsort(all_proxy))
    rho = float(np.corrcoef(rank_e, rank_p)[0, 1])
    lines.append(f"\nproxy check: Spearman rank correlation of E with the image error over "
                 f"{len(all_err)} renders: {rho:.3f}")
    lines.append("\nsegments needed to reach the image error of the uniform polyline with the "
                 "reference count (log-log interpolation):")
    for obj, table in results.items():
        base_rows = table["uniform"]
        ref_n = min(base_rows, key=lambda r: abs(r[0] - 31))
        target = ref_n[1]
        parts = []
        for rule, rows in table.items():
            ns = np.array([r[0] for r in rows], float)
            es = np.array([r[1] for r in rows], float)
            order = np.argsort(ns)
            ns, es = ns[order], es[order]
            below = np.flatnonzero(es <= target)
            if len(below) == 0:
                parts.append(f"{rule} >{int(ns[-1])}")
                continue
            k = below[0]
            if k == 0:
                parts.append(f"{rule} <={int(ns[0])}")
                continue
            x0, x1, y0, y1 = np.log(ns[k - 1]), np.log(ns[k]), np.log(es[k - 1]), np.log(es[k])
            x = x0 + (np.log(target) - y0) * (x1 - x0) / (y1 - y0) if y1 != y0 else x1
            parts.append(f"{rule} {np.exp(x):.0f}")
        lines.append(f"  {obj}: uniform N={ref_n[0]} error {target:.4f} -> " + ", ".join(parts))
    text = "\n".join(lines)
    print(text)
    (args.out / "open_problems.txt").write_text(text + "\n")

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import NullFormatter, ScalarFormatter

    # One colour per placement rule across all panels.
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
    fig.savefig(args.out / "open_problems.png", dpi=110)
    print(f"wrote {args.out / 'open_problems.png'}, {args.out / 'open_problems.txt'} "
          f"in {time.perf_counter() - t_start:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
