"""Kernel-only timing: exact B-spline lathe intersection vs the polyline
kernel on its 31-segment adaptive approximation (no path tracer).

The glass is the 12-segment B-spline of ``scripts/bench_spline.py``
(``lathe_shape.validation.reference.SPLINE_GLASS``). Three
ray sets, each ``--rays`` rays, in the lathe's local frame:

* ``camera``: the wine_glass camera's pinhole rays through a pixel grid
  covering the glass's bounding box on screen (primary rays);
* ``surface``: rays leaving random points of the surface in uniformly
  random directions (like reflected / refracted path segments);
* ``inside``: rays from random points of the bounding cylinder in random
  directions.

Kernels: nearest hit, shadow ray (``occl.``) and the first crossing of a
walk (``walk``: ``next_crossing_*``, which the path tracer calls).

Each kernel is compiled first, then all are timed in turn (``dr.eval`` +
``dr.sync_thread``), ``--repeat`` rounds; the table gives the median and
the min-max. ``--module PATH`` loads another version of the kernel (a copy
of the folder ``lathe_shape/kernels``, or its ``bspline.py``: see
:func:`load_kernel`); ``--baseline PATH`` times a second one interleaved
with it (before/after in one run). ``--threads 1`` times CPU
time on one Dr.Jit thread: on a shared machine far steadier than wall time.

    python scripts/bench_bspline_kernel.py [--rays 1000000] [--repeat 5] [--threads 1]
                                           [--module PATH] [--baseline PATH]
"""

from __future__ import annotations

import argparse
import functools
import importlib
import importlib.machinery
import importlib.util
import os
import sys
import time

import drjit as dr
import mitsuba as mi
import numpy as np

from lathe_shape.kernels import polyline as P
from lathe_shape.profiles import bspline as B
from lathe_shape.profiles.bspline import make_bspline_profile, to_polyline
from lathe_shape.profiles.polyline import make_profile
from lathe_shape.validation.reference import SPLINE_GLASS


def load_kernel(path: str | None, name: str = "_bench_alt"):
    """The B-spline kernel module: the package's, or another version at
    ``path``. The kernel is ``bspline.py`` with its sibling modules
    (``bspline_data.py``, ``bspline_roots.py``, ``bspline_traversal.py``,
    ``common.py``, ``trees.py``): ``path`` is a copy of the folder
    ``lathe_shape/kernels`` (e.g. ``git archive REV lathe_shape/kernels | tar
    -x -C DIR``, then ``DIR/lathe_shape/kernels``) or its ``bspline.py``,
    loaded with all its siblings as the package ``lathe_shape.<name>``. A
    single-file kernel of older versions (no ``bspline_data.py`` beside it)
    is loaded alone as ``lathe_shape.kernels.<name>``, so its relative
    imports resolve to the package's own modules."""
    if path is None:
        from lathe_shape.kernels import bspline
        return bspline
    folder = path if os.path.isdir(path) else os.path.dirname(os.path.abspath(path))
    if os.path.isdir(path) or os.path.exists(os.path.join(folder, "bspline_data.py")):
        package = f"lathe_shape.{name}"
        spec = importlib.machinery.ModuleSpec(package, None, is_package=True)
        spec.submodule_search_locations = [os.path.abspath(folder)]
        sys.modules[package] = importlib.util.module_from_spec(spec)
        return importlib.import_module(f"{package}.bspline")
    spec = importlib.util.spec_from_file_location(f"lathe_shape.kernels.{name}", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def camera_rays(seg: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Pinhole rays of the wine_glass camera (lookat (0,-52,24) -> (0,0,8);
    the glass sits at z = 0.001, so local z = world z - 0.001) through a
    square pixel grid covering the glass's screen bounding box."""
    eye = np.array([0.0, -52.0, 24.0 - 0.001])
    target = np.array([0.0, 0.0, 8.0 - 0.001])
    fwd = (target - eye) / np.linalg.norm(target - eye)
    right = np.cross(fwd, [0.0, 0.0, 1.0])
    right /= np.linalg.norm(right)
    up = np.cross(right, fwd)
    pts = seg.reshape(-1, 2)
    rmax, zmin, zmax = pts[:, 0].max(), pts[:, 1].min(), pts[:, 1].max()
    # Screen-space box of the bounding cylinder (8 corners of its square box).
    corners = np.array([[x, y, z] for x in (-rmax, rmax) for y in (-rmax, rmax)
                        for z in (zmin, zmax)]) - eye
    u = corners @ right / (corners @ fwd)
    v = corners @ up / (corners @ fwd)
    side = int(round(np.sqrt(n)))
    uu, vv = np.meshgrid(np.linspace(u.min(), u.max(), side), np.linspace(v.min(), v.max(), side))
    d = fwd[None, :] + uu.reshape(-1, 1) * right[None, :] + vv.reshape(-1, 1) * up[None, :]
    d /= np.linalg.norm(d, axis=1)[:, None]
    return np.tile(eye, (len(d), 1)), d


def surface_rays(seg: np.ndarray, n: int, rng) -> tuple[np.ndarray, np.ndarray]:
    """Rays leaving random surface points in uniformly random directions."""
    T = rng.uniform(0, len(seg), n)
    i = np.minimum(T.astype(int), len(seg) - 1)
    r, z = B.evaluate(seg, i, T - i)
    phi = rng.uniform(0, 2 * np.pi, n)
    org = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    return org + 1e-3 * d, d


def inside_rays(seg: np.ndarray, n: int, rng) -> tuple[np.ndarray, np.ndarray]:
    """Rays from random points of the bounding cylinder, random directions."""
    pts = seg.reshape(-1, 2)
    rmax, zmin, zmax = pts[:, 0].max(), pts[:, 1].min(), pts[:, 1].max()
    rad = rmax * np.sqrt(rng.uniform(size=n))
    phi = rng.uniform(0, 2 * np.pi, n)
    org = np.stack([rad * np.cos(phi), rad * np.sin(phi), rng.uniform(zmin, zmax, n)], axis=1)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1)[:, None]
    return org, d


def run_kernel(fn, o, d, clock) -> tuple[float, object]:
    """One timed evaluation of ``fn(o, d)``: ``(seconds, result)``."""
    t0 = clock()
    res = fn(o, d)
    dr.eval(res)
    dr.sync_thread()
    return clock() - t0, res


def interleaved_times(kernels: dict, o, d, repeat: int, clock) -> dict:
    """``repeat`` times of every kernel, run in turn (A B C A B C ...) so that
    a change in the machine's load affects all alike; each is first run once
    (compilation, or a load from the kernel cache). Returns ``{name:
    (times, hit fraction)}``."""
    hits = {}
    for name, fn in kernels.items():
        res = run_kernel(fn, o, d, clock)[1]
        valid = res if isinstance(res, mi.Bool) else res.valid
        hits[name] = float(np.mean(np.array(valid)))
    times: dict = {name: [] for name in kernels}
    for _ in range(repeat):
        for name, fn in kernels.items():
            times[name].append(run_kernel(fn, o, d, clock)[0])
    return {name: (times[name], hits[name]) for name in kernels}


def kernel_table(K, bdata, pdata, baseline=None) -> dict:
    """The timed kernels: the B-spline kernel of module ``K`` (and, given
    ``baseline = (module, data)``, that one's as well) and the polyline's:
    nearest hit, shadow ray (``occl.``) and the first crossing of a walk
    (``walk``, the query of the renders' path tracer)."""
    inf, on = mi.Float(dr.inf), mi.Bool(True)
    splines = [("bspline", K, bdata)] + ([("baseline", *baseline)] if baseline else [])
    kernels = {}
    for suffix, spline_fn, poly_fn in (
            ("", lambda M, b, o, d: M.intersect_bspline(b, o, d, inf, on),
             lambda o, d: P.intersect_polyline(pdata, o, d, inf, on)),
            (" occl.", lambda M, b, o, d: M.occluded_bspline(b, o, d, inf, on),
             lambda o, d: P.occluded_polyline(pdata, o, d, inf, on)),
            (" walk", lambda M, b, o, d: M.next_crossing_bspline(b, o, d, inf, on)[0],
             lambda o, d: P.next_crossing_polyline(pdata, o, d, inf, on)[0])):
        for name, module, data in splines:
            kernels[name + suffix] = functools.partial(spline_fn, module, data)
        kernels["polyline31" + suffix] = poly_fn
    return kernels


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--rays", type=int, default=1_000_000, help="rays per set (default: 1000000)")
    parser.add_argument("--repeat", type=int, default=5, help="timed runs per case (default: 5)")
    parser.add_argument("--variant", default="llvm_ad_rgb", help="Mitsuba variant (default: llvm_ad_rgb)")
    parser.add_argument("--module", default=None,
                        help="alternative kernel: a copy of lathe_shape/kernels, or its bspline.py")
    parser.add_argument("--baseline", default=None,
                        help="a second kernel (as --module), timed interleaved with the first")
    parser.add_argument("--threads", type=int, default=0,
                        help="Dr.Jit worker threads (0: default); with 1, times are CPU times")
    parser.add_argument("--sets", default="camera,surface,inside",
                        help="ray sets, comma-separated (default: camera,surface,inside)")
    args = parser.parse_args()
    mi.set_variant(args.variant)
    if args.threads:
        dr.set_thread_count(args.threads)
    # One thread: the process's CPU time, which the load of other processes
    # on the machine disturbs much less than the wall time.
    clock = time.process_time if args.threads == 1 else time.perf_counter
    K = load_kernel(args.module)
    spline = make_bspline_profile(SPLINE_GLASS, "spline glass")
    seg = spline.segment_controls
    bdata = K.build_bspline_data(seg)
    baseline = None
    if args.baseline:
        base_module = load_kernel(args.baseline, "_bench_baseline")
        baseline = (base_module, base_module.build_bspline_data(seg))
    prof = make_profile(to_polyline(seg, 32, "adaptive"), source="adaptive polyline")
    pdata = P.profile_polyline_data(prof, smooth=True)
    rng = np.random.default_rng(0)
    makers = {"camera": lambda: camera_rays(seg, args.rays),
              "surface": lambda: surface_rays(seg, args.rays, rng),
              "inside": lambda: inside_rays(seg, args.rays, rng)}
    kernels = kernel_table(K, bdata, pdata, baseline)
    print(f"{args.variant}, {args.rays} rays per set, median (min-max) of {args.repeat} interleaved "
          f"runs ({'CPU' if clock is time.process_time else 'wall'} time); spline of {len(seg)} segments, "
          f"polyline of {prof.segment_count}; kernel {args.module or 'lathe_shape/kernels/bspline.py'}"
          + (f", baseline {args.baseline}" if args.baseline else ""))
    print(f"{'rays':<10}{'kernel':<18}{'time [ms]':>22}{'Mrays/s':>9}{'hits':>7}{'bspline/this':>14}")
    for name in args.sets.split(","):
        org, d = makers[name]()
        o = mi.Point3f(org.T.astype(np.float32))
        dj = mi.Vector3f(d.T.astype(np.float32))
        dr.eval(o, dj)
        results = interleaved_times(kernels, o, dj, args.repeat, clock)
        medians = {k: float(np.median(t)) for k, (t, _) in results.items()}
        for kname, (times, hits) in results.items():
            t = medians[kname]
            ours = medians["bspline" + kname[kname.find(" "):] if " " in kname else "bspline"]
            ratio = "" if kname.startswith("bspline") else f"{ours / t:13.3f}x"
            spread = f"{t * 1e3:.1f} ({min(times) * 1e3:.1f}-{max(times) * 1e3:.1f})"
            print(f"{name:<10}{kname:<18}{spread:>22}{len(org) / t / 1e6:>9.2f}{hits:>7.3f}{ratio:>14}",
                  flush=True)


if __name__ == "__main__":
    main()
