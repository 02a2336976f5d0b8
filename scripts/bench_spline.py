"""Exact B-spline lathe (paper Method 2) against its polyline approximations
(Method 1) and POV-Ray's other cubic kinds, timed in one run.

The same glass -- a 12-segment uniform cubic B-spline -- is rendered exactly
as a B-spline and as curvature-adaptive polylines of 31 and 86 segments, in
the wine_glass scene with the same spp, seed and max_depth. The cubic kinds
of POV-Ray get a row each: ``bezier`` (the same curve, 4 points per
segment), ``catmull_rom`` (the curve through the B-spline's segment
joints: not quite the same curve) and ``quadratic`` (through 16 points of
the curve: 16 segments). Prints each
method's time (median and min-max of --repeat interleaved renders), the
spline/this time ratio (paper: about 18x for polylines; target for the cubic
kinds: at least 1/1.2) and the image difference to the exact spline render.

    python scripts/bench_spline.py [--resolution 256x256] [--spp 16] [--max-depth 8] [--repeat 5]
                                   [--seed 0] [--variant llvm_ad_rgb] [-D KEY=VALUE ...]
"""

from __future__ import annotations

from pathlib import Path

import mitsuba as mi
import numpy as np

from lathe_shape.tools.images import relative_error
from lathe_shape.validation.bench import bench_arguments, bench_scene, interleaved_render_times, median_spread
from lathe_shape.validation.reference import SPLINE_GLASS

ROOT = Path(__file__).resolve().parents[1]
GLASS_SCENE = ROOT / "scenes" / "wine_glass.xml"


def main() -> None:
    args = bench_arguments(__doc__.splitlines()[0], repeat=5)
    from lathe_shape.profiles.bspline import evaluate, make_bspline_profile, power_coefficients, to_polyline
    from lathe_shape.profiles.spline_kinds import bezier_points, catmull_rom_through, quadratic_through

    spline = make_bspline_profile(SPLINE_GLASS, "spline glass")
    width, height = args.size
    integrator = mi.load_dict({"type": "lathe_path", "max_depth": args.max_depth})
    print(f"variant {args.variant}, {width}x{height}, {args.spp} spp, max_depth {args.max_depth}, "
          f"median (min-max) of {args.repeat} interleaved renders; spline glass of "
          f"{spline.segment_count} segments")

    cases = {("exact B-spline", spline.segment_count):
             (bench_scene(args, GLASS_SCENE, SPLINE_GLASS, "bspline", mesh_segments="64"), integrator)}
    seg = spline.segment_controls
    joints = np.stack(evaluate(seg, np.r_[np.arange(len(seg)), len(seg) - 1],
                               np.r_[np.zeros(len(seg)), 1.0]), axis=1)
    joints[[0, -1], 0] = 0.0  # the glass's ends lie on the axis
    # A quadratic spline through the joints overshoots the glass's thin rim
    # (it is not C1): it goes through 16 points uniform in t instead, plus
    # the midpoint of the last chord (a straight last piece onto the axis).
    through = to_polyline(seg, 16, "uniform")
    through = np.concatenate([through[:-1], (through[-2:-1] + through[-1:]) / 2, through[-1:]])
    for kind, points, count in (("bezier", bezier_points(power_coefficients(seg)), len(seg)),
                                ("catmull_rom", catmull_rom_through(joints), len(seg)),
                                ("quadratic", quadratic_through(through), len(through) - 1)):
        scene = bench_scene(args, GLASS_SCENE, points, kind, mesh_segments="64")
        cases[(f"exact {kind}", count)] = (scene, integrator)
    for segments in (31, 86):
        for method in ("adaptive", "uniform"):
            poly = to_polyline(spline.segment_controls, segments + 1, method)
            scene = bench_scene(args, GLASS_SCENE, poly, "polyline", mesh_segments="64")
            cases[(f"{method} polyline", segments)] = (scene, integrator)
    times = interleaved_render_times(cases, args.spp, args.repeat, args.seed)
    images = {key: mi.render(scene, spp=args.spp, seed=args.seed, integrator=integrator).numpy()
              for key, (scene, _) in cases.items()}
    spline_key = next(iter(cases))
    t_spline = median_spread(times[spline_key])[0]
    print(f"\n{'profile':<22}{'segments':>9}{'time [s]':>24}{'spline/this':>13}{'rel. error':>12}")
    for key, values in times.items():
        median, low, high = median_spread(values)
        error = relative_error(images[key], images[spline_key])
        print(f"{key[0]:<22}{key[1]:>9}{f'{median:.3f} ({low:.3f}-{high:.3f})':>24}"
              f"{t_spline / median:>12.2f}x{error:>12.4f}", flush=True)
    print("\nrel. error = mean |this - spline| / mean spline, same seed (correlated noise); "
          "catmull_rom and quadratic are not quite the same curve")


if __name__ == "__main__":
    main()
