"""``lathe-profile``: check a profile file, or turn a B-spline profile into a
polyline profile of N points.

Examples::

    lathe-profile scenes/wine_glass.csv                                  # validate + summary
    lathe-profile glass.csv --kind bspline --to-polyline 32              # CSV on stdout
    lathe-profile glass.csv --kind bspline --to-polyline 32 -o out       # writes out/glass_32.csv
"""

from __future__ import annotations

import argparse
import os
import sys

from .common import CliError, run_command

__all__ = ["MAX_POLYLINE_POINTS", "main", "build_parser"]

#: Most points ``--to-polyline`` writes (the polyline is validated as a
#: profile, and written as text: a million points is about 20 MB of CSV).
MAX_POLYLINE_POINTS = 1_000_000


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
                        help="B-spline only: write a polyline of N points of the same curve "
                             f"(3 <= N <= {MAX_POLYLINE_POINTS:,})")
    parser.add_argument("--method", choices=("uniform", "adaptive"), default="adaptive",
                        help="point placement for --to-polyline: uniform in t, or curvature-adaptive "
                             "(nearly constant turning angle, the paper's advice; default)")
    parser.add_argument("-o", "--output", metavar="DIR",
                        help="output folder, created if missing: --to-polyline writes "
                             "DIR/<input stem>_<N>.csv (default: the CSV goes to stdout)")
    return parser


def describe_polyline(path: str, points, sharp, labels, crease_angle: float) -> str:
    """Validate polyline points; the one-line summary."""
    import numpy as np

    from ..profiles import make_profile

    polyline = make_profile(points, sharp, labels, source=path, crease_angle=crease_angle)
    r_max, z_min, z_max = polyline.bounds()
    form = "closed loop" if polyline.closed_loop else "both ends on the axis"
    creases = int(np.sum(np.any(polyline.normal_end[:-1] != polyline.normal_start[1:], axis=1)))
    return (f"{path}: valid polyline profile, {len(polyline.points)} points, "
            f"{polyline.segment_count} surface segments, {form}, r <= {r_max:g}, "
            f"z in [{z_min:g}, {z_max:g}], {creases} creases at {crease_angle:g} deg")


def describe_bspline(path: str, spline) -> str:
    """The one-line summary of a validated B-spline profile."""
    r_max, z_min, z_max = spline.bounds()
    form = "closed periodic" if spline.closed_loop else "open, ends on the axis"
    return (f"{path}: valid cubic B-spline profile, {len(spline.points)} control points, "
            f"{spline.segment_count} curve segments, {form}, r <= {r_max:g}, "
            f"z in [{z_min:g}, {z_max:g}]")


def convert(args: argparse.Namespace, spline) -> int:
    """``--to-polyline N``: the polyline CSV, to stdout or DIR/<stem>_<N>.csv."""
    from ..profiles import format_profile_csv, make_profile
    from ..profiles.bspline import to_polyline
    from .common import output_folder

    if args.to_polyline < 3:
        raise CliError(f"--to-polyline needs at least 3 points, got {args.to_polyline}")
    if args.to_polyline > MAX_POLYLINE_POINTS:
        raise CliError(f"--to-polyline must be at most {MAX_POLYLINE_POINTS:,} points, "
                       f"got {args.to_polyline:,}")
    polyline = to_polyline(spline.segment_controls, args.to_polyline, args.method)
    # The result must itself be a valid polyline profile.
    make_profile(polyline, source=f"polyline of {args.input}")
    text = format_profile_csv(
        polyline, header=f"{len(polyline)} points: {args.method} polyline of the B-spline {args.input}")
    if args.output is None:
        sys.stdout.write(text)
        return 0
    stem = os.path.splitext(os.path.basename(args.input))[0]
    path = os.path.join(output_folder(args.output), f"{stem}_{args.to_polyline}.csv")
    with open(path, "w", encoding="utf-8") as f:
        f.write(text)
    print(f"wrote {path} ({len(polyline)} points)", file=sys.stderr)
    return 0


def check_profile(args: argparse.Namespace) -> int:
    """The command: :func:`check_or_convert`, with no traceback whatever the
    input (profile errors are ValueErrors, which :func:`run_command` reports;
    running out of memory or an arithmetic overflow is reported here)."""
    try:
        return check_or_convert(args)
    except MemoryError:
        raise CliError(f"{args.input}: out of memory (the profile, or the --to-polyline "
                       f"point count, is too large for this machine)") from None
    except (CliError, ValueError, RuntimeError, OSError):
        raise
    except Exception as e:  # a bug; still a one-line message, naming the input
        raise CliError(f"{args.input}: unexpected {type(e).__name__}: {e}") from None


def check_or_convert(args: argparse.Namespace) -> int:
    """Validate the profile and print its summary, or convert it."""
    from ..profiles import make_bspline_profile, read_points

    points, sharp, labels = read_points(args.input)
    if args.kind == "polyline":
        if args.to_polyline is not None:
            raise CliError("--to-polyline needs --kind bspline (the input is already a polyline)")
        print(describe_polyline(args.input, points, sharp, labels, args.crease_angle))
        return 0
    spline = make_bspline_profile(points, args.input)
    if args.to_polyline is None:
        print(describe_bspline(args.input, spline))
        return 0
    return convert(args, spline)


def main(argv: list[str] | None = None) -> int:
    return run_command("lathe-profile", build_parser(), check_profile, argv)


if __name__ == "__main__":
    sys.exit(main())
