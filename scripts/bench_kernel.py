"""Kernel-only throughput of ``intersect_polyline``: 31, 300 and 1000 segments.

All profiles are the same glass (a cup with a solid base and curved walls)
sampled with different segment counts. Rays come from a pinhole camera
looking at the glass (about half of them hit). After one compiling call per
profile, the profiles are timed in interleaved rounds (31, 300, 1000, 31,
...) and each reports the median of its rounds: wall time, or with
``--threads 1`` the process's CPU time on one Dr.Jit thread (robust on a
busy machine).

Usage: ``python scripts/bench_kernel.py [n_rays] [--rounds 7] [--threads N] [--variant llvm_ad_rgb]``
"""

from __future__ import annotations

import argparse
import time

import drjit as dr
import mitsuba as mi
import numpy as np

from lathe_shape.kernels.polyline import build_polyline_data, intersect_polyline

SEGMENTS = (31, 300, 1000)


def glass_points(n_seg: int) -> np.ndarray:
    """Clockwise glass profile with about ``n_seg`` segments."""
    mi_ = (n_seg - 1) // 2
    mo = n_seg - 1 - mi_
    zi = np.linspace(0.2, 2.0, mi_)
    ri = 0.5 + 0.3 * np.sin(1.4 * zi)
    zo = np.linspace(2.0, 0.0, mo)
    ro = 0.56 + 0.3 * np.sin(1.4 * zo) + 0.06 * (zo < 0.2)
    pts = np.vstack([[[0.0, 0.2]], np.stack([ri, zi], 1),
                     np.stack([ro, zo], 1), [[0.0, 0.0]]])
    return pts


def profile_data(n_seg: int):
    """Segment count and kernel data (flat normals) of the benchmark glass."""
    pts = glass_points(n_seg)
    return len(pts) - 1, build_polyline_data(pts[:-1], pts[1:])


def camera_rays(n: int):
    """Pinhole rays from (0, -5, 1.5) towards the glass, in local frame."""
    side = int(np.sqrt(n))
    x, y = np.meshgrid(np.linspace(-0.25, 0.25, side),
                       np.linspace(-0.25, 0.25, side))
    d = np.stack([x.ravel(), np.ones(x.size), y.ravel() - 0.1], 0)
    o = np.tile(np.array([[0.0], [-5.0], [1.5]]), (1, x.size))
    return (mi.Point3f(o.astype(np.float32)),
            mi.Vector3f(d.astype(np.float32)))


def timed_query(data, o, d, clock) -> tuple[float, float]:
    """``(seconds by clock, hit rate)`` of one evaluated nearest-hit query
    over all rays."""
    n = dr.width(o)
    start = clock()
    hit = intersect_polyline(data, o, d, dr.full(mi.Float, dr.inf, n), dr.full(mi.Bool, True, n))
    dr.eval(hit.t, hit.seg, hit.u, hit.valid)
    dr.sync_thread()
    return clock() - start, dr.mean(mi.Float(hit.valid))[0]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("n_rays", nargs="?", type=int, default=1 << 20, help="rays (default 2^20)")
    parser.add_argument("--rounds", type=int, default=7, help="interleaved timed rounds (default 7)")
    parser.add_argument("--threads", type=int, default=None,
                        help="Dr.Jit threads (default: all); 1 times the process's CPU time")
    parser.add_argument("--variant", default="llvm_ad_rgb", help="Mitsuba JIT variant")
    args = parser.parse_args()
    mi.set_variant(args.variant)
    if args.threads is not None:
        dr.set_thread_count(args.threads)
    clock = time.process_time if args.threads == 1 else time.perf_counter
    o, d = camera_rays(args.n_rays)
    cases = {n_seg: profile_data(n_seg) for n_seg in SEGMENTS}
    hit_rate = {n_seg: timed_query(data, o, d, clock)[1] for n_seg, (_, data) in cases.items()}
    times: dict[int, list[float]] = {n_seg: [] for n_seg in SEGMENTS}
    for _ in range(args.rounds):
        for n_seg, (_, data) in cases.items():
            times[n_seg].append(timed_query(data, o, d, clock)[0])
    unit = "CPU ms, 1 thread" if args.threads == 1 else "ms"
    median = {n_seg: float(np.median(t)) for n_seg, t in times.items()}
    for n_seg, (n, _) in cases.items():
        print(f"{n:5d} segments: {dr.width(o) / median[n_seg] / 1e6:7.2f} Mrays/s "
              f"({median[n_seg] * 1e3:6.1f} {unit}, hit rate {hit_rate[n_seg]:.2f})")
    for n_seg in SEGMENTS[1:]:
        print(f"time ratio {n_seg} / {SEGMENTS[0]} segments: {median[n_seg] / median[SEGMENTS[0]]:.2f}")


if __name__ == "__main__":
    main()
