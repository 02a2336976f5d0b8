"""Speed of profile gradients: one backward pass of ``lathe_prb`` (the
gradient of the image with respect to the lathe's profile points) against
the primal render of ``lathe_path``, at equal spp, on the diffuse-vase scene
of ``lathe_shape.tools.diff_scenes`` (polyline or B-spline profile), or
(``--kind glass``) on the clear wine glass (scenes/wine_glass.csv) of
``glass_scene`` in front of its textured backdrop. Prints the medians of
--repeat interleaved runs and their ratio (the target is at most 3).

    python scripts/bench_gradients.py [--resolution 256x256] [--spp 16] [--max-depth 8] [--repeat 3]
                                      [--kind polyline|bspline|glass] [--variant llvm_ad_rgb]
"""

from __future__ import annotations

from pathlib import Path

import mitsuba as mi

from lathe_shape.tools.diff_scenes import glass_scene, lathe_scene
from lathe_shape.tools.gradients import gradient_times
from lathe_shape.validation.bench import bench_arguments, median_spread


def main(argv: list[str] | None = None) -> None:
    def kind_option(parser):
        parser.add_argument("--kind", choices=("polyline", "bspline", "glass"), default="polyline",
                            help="the vase's profile kind, or the clear wine glass (default: polyline)")

    args = bench_arguments(__doc__.splitlines()[0], argv, extra=kind_option)
    width, height = args.size
    if height != width:
        raise SystemExit("bench_gradients.py: --resolution must be square (WxW)")
    primal = {"type": "lathe_path", "max_depth": args.max_depth}
    if args.kind == "glass":
        wine_glass = Path(__file__).resolve().parent.parent / "scenes" / "wine_glass.csv"
        scene = glass_scene(str(wine_glass), resolution=width, max_depth=args.max_depth)
        # glass_scene's lathe_prb has no Russian roulette: nor has the primal
        primal["rr_depth"] = args.max_depth
    else:
        scene = lathe_scene(kind=args.kind, resolution=width, max_depth=args.max_depth)
    primal = mi.load_dict(primal)
    times = gradient_times(scene, primal, args.spp, args.repeat, args.seed)
    medians = {}
    for name, values in times.items():
        median, low, high = median_spread(values)
        medians[name] = median
        print(f"{name:9s} {median:8.3f} s  (min {low:.3f}, max {high:.3f})")
    print(f"backward / primal = {medians['backward'] / medians['primal']:.2f}  "
          f"({args.kind}, {width}x{height}, {args.spp} spp, max_depth {args.max_depth})")


if __name__ == "__main__":
    main()
