"""Time of a big polyline lathe's first render, split into its parts (issue 24, item 7).

A closed wavy, noisy vase profile of N points (numpy) is written to a CSV;
the script then times, in this one process:

* ``validate``: reading and validating the profile (``make_profile``),
* ``tree``: the segment tree alone (``child_box_arrays`` on the segment
  boxes, as ``build_polyline_data`` builds it: ``sah_tree`` up to
  ``CLUSTERED_ABOVE`` segments, ``clustered_tree`` above) and, with ``--old``, the same
  tree and node records by the recursive builder it replaced
  (``_sah_split`` + ``_store_copies``), the ratio and whether both are
  bit for bit the same (up to ``CLUSTERED_ABOVE`` segments),
* ``kernel data``: all of ``build_polyline_data``,
* ``load``: ``mi.load_dict`` of a scene with the lathe (``--reference``),
* ``first render`` / ``second render``: ``W x H`` at 1 spp with ``lathe_path``,

and prints each with the process's peak resident memory (``ru_maxrss``)
after it.

    python scripts/bench_tree_build.py [--points 100000 1000000] [--reference proxy|mesh]
                                       [--resolution 64] [--old] [--no-render] [--variant llvm_ad_rgb]
"""

from __future__ import annotations

import argparse
import resource
import tempfile
import time
from pathlib import Path

import numpy as np

from lathe_shape.validation.bench import square_side


def vase_points(n: int, seed: int = 0) -> np.ndarray:
    """A closed vase profile of ``n`` points: from the axis at the bottom out,
    up a wavy, slightly noisy outer wall, back to the axis at the top
    (clockwise, z increasing along the wall: no self-intersection)."""
    rng = np.random.default_rng(seed)
    z = np.linspace(0.0, 10.0, n - 2)
    r = 2.0 + 0.6 * np.sin(1.3 * z) + 0.25 * np.sin(17.0 * z) + 0.002 * rng.standard_normal(n - 2)
    wall = np.stack([r, z], axis=1)
    return np.vstack([[[0.0, 0.0]], wall, [[0.0, 10.0]]])


def peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def timed(label: str, fn):
    t0 = time.perf_counter()
    out = fn()
    print(f"  {label:<22} {time.perf_counter() - t0:8.3f} s   peak RSS {peak_mb():8.0f} MB", flush=True)
    return out, time.perf_counter() - t0


def segment_boxes(profile) -> np.ndarray:
    """The padded segment boxes ``build_polyline_data`` builds its tree over
    (without the unit frame: the tree does not depend on it)."""
    p0, p1 = profile.segment_points()
    pad = 8e-5 * float(np.abs(np.concatenate([p0, p1])).max())
    return np.stack([np.maximum(np.minimum(p0[:, 0], p1[:, 0]) - pad, 0.0),
                     np.maximum(p0[:, 0], p1[:, 0]) + pad,
                     np.minimum(p0[:, 1], p1[:, 1]) - pad,
                     np.maximum(p0[:, 1], p1[:, 1]) + pad], axis=1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--points", type=int, nargs="+", default=[100_000, 1_000_000],
                        help="profile point counts (default: 100000 1000000)")
    parser.add_argument("--reference", default="proxy", choices=("proxy", "mesh"),
                        help="the lathe's stand-in in Mitsuba's scene (default: proxy)")
    parser.add_argument("--resolution", type=square_side, default=64, metavar="NxN",
                        help="render size, NxN or N (default: 64x64)")
    parser.add_argument("--old", action="store_true", help="also time the recursive builder (default: off)")
    parser.add_argument("--no-render", action="store_true", help="time the tree builds only (default: off)")
    parser.add_argument("--variant", default="llvm_ad_rgb", help="Mitsuba variant (default: llvm_ad_rgb)")
    args = parser.parse_args()

    import mitsuba as mi
    mi.set_variant(args.variant)
    import lathe_shape  # noqa: F401 (registers the plugin)

    with tempfile.TemporaryDirectory() as tmp:
        for n in args.points:
            one_profile(n, args, Path(tmp))


def one_profile(n: int, args, tmp: Path) -> None:
    """The timings of one profile of ``n`` points."""
    import mitsuba as mi

    from lathe_shape.kernels import common
    from lathe_shape.kernels.polyline import _node_records, profile_polyline_data
    from lathe_shape.profiles import make_profile, write_profile_csv

    print(f"{n:,} points (reference={args.reference}):", flush=True)
    points = vase_points(n)
    csv = write_profile_csv(tmp / f"vase_{n}.csv", points)
    profile, _ = timed("validate", lambda: make_profile(points))
    box = segment_boxes(profile)
    leaf_rec = np.arange(8.0 * len(box)).reshape(-1, 8)
    new, t_new = timed("tree", lambda: common.child_box_arrays(box))
    if args.old:
        old, t_old = timed("tree (recursive)", lambda: common._child_box_bvh_recursive(
            box, lambda b: [b[1] * b[1], common.box_rmin2(b[0]), b[2], b[3]], lambda k, b: leaf_rec[k]))
        same = (np.array_equal(np.asarray(old[0], np.float32).view(np.uint32),
                               _node_records(new, leaf_rec).view(np.uint32))
                and np.array_equal(np.asarray(old[1], np.uint32), new.links))
        print(f"  recursive / new        {t_old / t_new:8.1f} x   identical: {same}", flush=True)
        del old
    del new
    timed("kernel data", lambda: profile_polyline_data(profile))
    if args.no_render:
        return
    scene_dict = {
        "type": "scene",
        "integrator": {"type": "lathe_path", "max_depth": 4},
        "sensor": {"type": "perspective", "fov": 40,
                   "to_world": mi.ScalarTransform4f().look_at(origin=[0, -30, 5], target=[0, 0, 5],
                                                              up=[0, 0, 1]),
                   "film": {"type": "hdrfilm", "width": args.resolution, "height": args.resolution},
                   "sampler": {"type": "independent", "sample_count": 1}},
        "emitter": {"type": "constant"},
        "vase": {"type": "lathe", "filename": str(csv), "reference": args.reference,
                 "bsdf": {"type": "diffuse"}},
    }
    scene, _ = timed("load", lambda: mi.load_dict(scene_dict))
    timed("first render", lambda: mi.render(scene, spp=1).numpy())
    timed("second render", lambda: mi.render(scene, spp=1, seed=1).numpy())

if __name__ == "__main__":
    main()
