"""Kernel-only throughput of ``intersect_polyline``: 31 vs 300 segments.

Both profiles are the same glass (a cup with a solid base and curved walls)
sampled with different segment counts. Rays come from a pinhole camera
looking at the glass (about half of them hit); each timing excludes the
first (compiling) call and takes the best of several runs.

Usage: ``python scripts/bench_kernel.py [n_rays] [--variant llvm_ad_rgb]``
"""

from __future__ import annotations

import argparse
import time

import drjit as dr
import mitsuba as mi
import numpy as np

from lathe_shape.kernels.polyline import build_polyline_data, intersect_polyline


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


def bench(data, o, d, repeats: int = 5) -> float:
    """Best wall time of one evaluated nearest-hit query over all rays."""
    n = dr.width(o)
    tmax = dr.full(mi.Float, dr.inf, n)
    active = dr.full(mi.Bool, True, n)
    best = np.inf
    for i in range(repeats + 1):
        start = time.perf_counter()
        hit = intersect_polyline(data, o, d, tmax, active)
        dr.eval(hit.t, hit.seg, hit.u, hit.valid)
        dr.sync_thread()
        if i > 0:
            best = min(best, time.perf_counter() - start)
    return best, dr.mean(mi.Float(hit.valid))[0]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("n_rays", nargs="?", type=int, default=1 << 20, help="rays (default 2^20)")
    parser.add_argument("--variant", default="llvm_ad_rgb", help="Mitsuba JIT variant")
    args = parser.parse_args()
    mi.set_variant(args.variant)
    n_rays = args.n_rays
    o, d = camera_rays(n_rays)
    rates = {}
    for n_seg in (31, 300):
        n, data = profile_data(n_seg)
        seconds, hit_rate = bench(data, o, d)
        rates[n_seg] = dr.width(o) / seconds
        print(f'{n:4d} segments: {rates[n_seg] / 1e6:7.2f} Mrays/s '
              f'({seconds * 1e3:6.1f} ms, hit rate {hit_rate:.2f})')
    print(f'time ratio 300 / 31 segments: {rates[31] / rates[300]:.2f}')


if __name__ == '__main__':
    main()
