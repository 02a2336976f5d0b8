"""Exact B-spline lathe (paper Method 2) against its polyline approximations
(Method 1), timed in one run.

The same glass -- a 12-segment uniform cubic B-spline -- is rendered exactly
as a B-spline and as curvature-adaptive polylines of 31 and 86 segments, in
the wine_glass scene with the same spp, seed and max_depth. Prints each
method's time, the spline/polyline time ratio (paper: about 18x; target
<= 1.5x) and the image difference to the exact spline render.

    python scripts/bench_spline.py [--resolution 256x256] [--spp 16] [--max-depth 8] [--repeat 3]
                                   [--seed 0] [--variant llvm_ad_rgb] [-D KEY=VALUE ...]
"""

from __future__ import annotations

from pathlib import Path

import mitsuba as mi

from lathe_shape.tools.bench import bench_arguments, bench_scene, best_render_time
from lathe_shape.tools.images import relative_error
from lathe_shape.tools.reference import SPLINE_GLASS

ROOT = Path(__file__).resolve().parents[1]
GLASS_SCENE = ROOT / "scenes" / "wine_glass.xml"


def main() -> None:
    args = bench_arguments(__doc__.splitlines()[0])
    from lathe_shape.profiles.bspline import make_bspline_profile, to_polyline

    spline = make_bspline_profile(SPLINE_GLASS, "spline glass")
    width, height = args.size
    integrator = mi.load_dict({"type": "lathe_path", "max_depth": args.max_depth})
    print(f"variant {args.variant}, {width}x{height}, {args.spp} spp, max_depth {args.max_depth}, "
          f"best of {args.repeat}; spline glass of {spline.segment_count} segments")

    spline_scene = bench_scene(args, GLASS_SCENE, SPLINE_GLASS, "bspline", mesh_segments="64")
    t_spline, img_spline = best_render_time(spline_scene, integrator, args.spp, args.repeat, args.seed)
    print(f"\n{'profile':<28}{'segments':>9}{'time [s]':>10}{'spline/this':>13}{'rel. error':>12}")
    print(f"{'exact B-spline':<28}{spline.segment_count:>9}{t_spline:>10.3f}{1.0:>12.2f}x{0.0:>12.4f}")
    for segments in (31, 86):
        for method in ("adaptive", "uniform"):
            poly = to_polyline(spline.segment_controls, segments + 1, method)
            poly_scene = bench_scene(args, GLASS_SCENE, poly, "polyline", mesh_segments="64")
            t_poly, img_poly = best_render_time(poly_scene, integrator, args.spp, args.repeat, args.seed)
            err = relative_error(img_poly, img_spline)
            print(f"{method + ' polyline':<28}{segments:>9}{t_poly:>10.3f}{t_spline / t_poly:>12.2f}x"
                  f"{err:>12.4f}", flush=True)
    print("\nrel. error = mean |polyline - spline| / mean spline, same seed (correlated noise)")


if __name__ == "__main__":
    main()
