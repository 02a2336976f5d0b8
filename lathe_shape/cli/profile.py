"""``lathe-profile``: check a profile file, or turn a B-spline profile into a
polyline profile of N points.

Examples::

    lathe-profile scenes/wine_glass.csv                          # validate + summary
    lathe-profile glass_spline.csv --kind bspline --to-polyline 32 --method adaptive -o glass_32.csv
"""

from __future__ import annotations

import argparse
import sys

__all__ = ["main", "build_parser"]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="lathe-profile",
        description="Validate a lathe profile, or convert a B-spline profile to a polyline.",
    )
    parser.add_argument("input", help="profile file (CSV r,z[,sharp], or a .json/.toml arc spec)")
    parser.add_argument("--kind", choices=("polyline", "bspline"), default="polyline",
                        help="how to read the points (default: polyline)")
    parser.add_argument("--crease-angle", type=float, default=30.0,
                        help="crease angle in degrees (default 30)")
    parser.add_argument("--to-polyline", type=int, metavar="N",
                        help="B-spline only: write a polyline of N points of the same curve")
    parser.add_argument("--method", choices=("uniform", "adaptive"), default="adaptive",
                        help="point placement for --to-polyline: uniform in t, or curvature-adaptive "
                             "(nearly constant turning angle, the paper's advice; default)")
    parser.add_argument("-o", "--output", help="output CSV for --to-polyline (default: stdout)")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    import numpy as np

    from ..profiles import bspline as bs
    from ..profiles.bspline import make_bspline_profile
    from ..profiles.polyline import make_profile, read_profile_csv

    def fail(message: str) -> int:
        print(f"lathe-profile: error: {message}", file=sys.stderr)
        return 2

    try:
        if args.input.lower().endswith((".json", ".toml")):
            from ..profiles.arcs import load_profile_spec

            points, sharp, labels = load_profile_spec(args.input)
        else:
            points, sharp, labels = read_profile_csv(args.input)
        if args.kind == "polyline":
            if args.to_polyline is not None:
                return fail("--to-polyline needs --kind bspline (the input is already a polyline)")
            prof = make_profile(points, sharp, labels, source=args.input, crease_angle=args.crease_angle)
            r_max, z_min, z_max = prof.bounds()
            form = "closed loop" if prof.closed_loop else "both ends on the axis"
            creases = int(np.sum(np.any(prof.normal_end[:-1] != prof.normal_start[1:], axis=1)))
            print(f"{args.input}: valid polyline profile, {len(prof.points)} points, "
                  f"{prof.segment_count} surface segments, {form}, r <= {r_max:g}, "
                  f"z in [{z_min:g}, {z_max:g}], {creases} creases at {args.crease_angle:g} deg")
            return 0
        spline = make_bspline_profile(points, args.input)
        if args.to_polyline is None:
            r_max, z_min, z_max = spline.bounds()
            form = "closed periodic" if spline.closed_loop else "open, ends on the axis"
            print(f"{args.input}: valid cubic B-spline profile, {len(spline.points)} control points, "
                  f"{spline.segment_count} curve segments, {form}, r <= {r_max:g}, "
                  f"z in [{z_min:g}, {z_max:g}]")
            return 0
        if args.to_polyline < 3:
            return fail(f"--to-polyline needs at least 3 points, got {args.to_polyline}")
        poly = bs.to_polyline(spline.segment_controls, args.to_polyline, args.method)
        # The result must itself be a valid polyline profile.
        make_profile(poly, source=f"polyline of {args.input}")
    except (OSError, ValueError) as e:
        return fail(str(e))
    lines = [f"# {len(poly)} points: {args.method} polyline of the B-spline {args.input}", "r,z"]
    lines += [f"{r:.9g},{z:.9g}" for r, z in poly]
    text = "\n".join(lines) + "\n"
    if args.output:
        with open(args.output, "w", encoding="utf-8") as f:
            f.write(text)
        print(f"wrote {args.output} ({len(poly)} points)", file=sys.stderr)
    else:
        sys.stdout.write(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
