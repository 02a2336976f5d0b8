"""``lathe-profile``: check a profile file, turn a curve profile (any kind
but ``polyline``) into a polyline profile of N points, or import the
``lathe``/``sor`` blocks of a POV-Ray scene.

Examples::

    lathe-profile scenes/wine_glass.csv                                  # validate + summary
    lathe-profile glass.csv --kind bspline --to-polyline 32              # CSV on stdout
    lathe-profile glass.csv --kind bspline --to-polyline 32 -o out       # writes out/glass_32.csv
    lathe-profile cup.csv --kind bezier --open                           # an open sheet
    lathe-profile --from-pov vases.pov -o profiles                       # NAME.csv + NAME.xml per block

A CSV's ``# kind: NAME`` and ``# open: true`` lines (as ``--from-pov``
writes them) stand for ``--kind`` and ``--open``.
"""

from __future__ import annotations

import argparse
import os
import sys

from .common import CliError, run_command

__all__ = ["MAX_POLYLINE_POINTS", "PROFILE_KINDS", "main", "build_parser"]

#: The ``--kind`` values (the lathe plugin's kinds).
PROFILE_KINDS = ("polyline", "bspline", "bezier", "catmull_rom", "quadratic", "sor")

#: Most points ``--to-polyline`` writes (the polyline is validated as a
#: profile, and written as text: a million points is about 20 MB of CSV).
MAX_POLYLINE_POINTS = 1_000_000


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="lathe-profile",
        description="Validate a lathe profile, convert a curve profile to a polyline, or import "
                    "the lathe and sor blocks of a POV-Ray file.",
    )
    parser.add_argument("input", nargs="?",
                        help="profile file (CSV r,z[,sharp], or a .json/.toml arc spec)")
    parser.add_argument("--kind", choices=PROFILE_KINDS, default=None,
                        help="how to read the points (default: the CSV's '# kind:' line, else polyline)")
    parser.add_argument("--open", action="store_true",
                        help="the profile is a single open sheet (default: the CSV's '# open:' line)")
    parser.add_argument("--from-pov", metavar="FILE.pov",
                        help="import the literal lathe and sor blocks of a POV-Ray file: writes "
                             "NAME.csv and a Mitsuba <shape> snippet NAME.xml per block into -o DIR "
                             "(default: next to FILE.pov)")
    parser.add_argument("--crease-angle", type=float, default=30.0,
                        help="crease angle in degrees (default 30)")
    parser.add_argument("--to-polyline", type=int, metavar="N",
                        help="curve kinds only: write a polyline of N points of the same curve "
                             f"(3 <= N <= {MAX_POLYLINE_POINTS:,})")
    parser.add_argument("--method", choices=("uniform", "adaptive"), default="adaptive",
                        help="point placement for --to-polyline: uniform in t, or curvature-adaptive "
                             "(nearly constant turning angle, the paper's advice; default)")
    parser.add_argument("-o", "--output", metavar="DIR",
                        help="output folder, created if missing: --to-polyline writes "
                             "DIR/<input stem>_<N>.csv (default: the CSV goes to stdout)")
    return parser


def describe_polyline(path: str, points, sharp, labels, crease_angle: float,
                      open_sheet: bool = False) -> str:
    """Validate polyline points; the one-line summary."""
    import numpy as np

    from ..profiles import make_profile

    polyline = make_profile(points, sharp, labels, source=path, crease_angle=crease_angle,
                            open_sheet=open_sheet)
    r_max, z_min, z_max = polyline.bounds()
    form = ("open sheet" if open_sheet else
            "closed loop" if polyline.closed_loop else "both ends on the axis")
    creases = int(np.sum(np.any(polyline.normal_end[:-1] != polyline.normal_start[1:], axis=1)))
    return (f"{path}: valid polyline profile, {len(polyline.points)} points, "
            f"{polyline.segment_count} surface segments, {form}, r <= {r_max:g}, "
            f"z in [{z_min:g}, {z_max:g}], {creases} creases at {crease_angle:g} deg")


def describe_bspline(path: str, spline) -> str:
    """The one-line summary of a validated curve profile (any kind but
    polyline)."""
    r_max, z_min, z_max = spline.bounds()
    if spline.kind == "bspline":
        form = "closed periodic" if spline.closed_loop else "open, ends on the axis"
        what = "cubic B-spline profile"
    else:
        form = ("open sheet" if spline.open_sheet else "closed loop" if spline.closed_loop
                else "solid, ends on the axis")
        what = f"{spline.kind} profile"
    return (f"{path}: valid {what}, {len(spline.points)} control points, "
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
    if spline.kind == "sor":
        polyline = spline.to_polyline(args.to_polyline, args.method)
    else:
        polyline = to_polyline(spline.segment_controls, args.to_polyline, args.method)
    # The result must itself be a valid polyline profile.
    make_profile(polyline, source=f"polyline of {args.input}", open_sheet=spline.open_sheet)
    text = format_profile_csv(
        polyline, header=f"{len(polyline)} points: {args.method} polyline of the {spline.kind} {args.input}",
        options={"open": True} if spline.open_sheet else None)
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
    """Validate the profile and print its summary, convert it, or import a
    POV-Ray file."""
    from ..profiles import make_bspline_profile, read_points, read_profile_options
    from ..surfaces import make_surface

    if (args.input is None) == (args.from_pov is None):
        raise CliError("give a profile file, or --from-pov FILE.pov (not both)")
    if args.from_pov is not None:
        return import_pov(args.from_pov, args.output)
    points, sharp, labels = read_points(args.input)
    declared = read_profile_options(args.input)
    kind = args.kind or declared.get("kind", "polyline")
    open_sheet = args.open or declared.get("open", False)
    if kind not in PROFILE_KINDS:
        raise CliError(f"{args.input}: unknown profile kind '{kind}' (expected one of: "
                       f"{', '.join(PROFILE_KINDS)})")
    if kind == "polyline":
        if args.to_polyline is not None:
            raise CliError("--to-polyline needs a curve --kind (the input is already a polyline)")
        print(describe_polyline(args.input, points, sharp, labels, args.crease_angle, open_sheet))
        return 0
    if kind == "bspline" and not open_sheet:
        spline = make_bspline_profile(points, args.input)
    else:
        spline = make_surface(kind, points, sharp, labels, args.input, open_sheet=open_sheet).profile
    if args.to_polyline is None:
        print(describe_bspline(args.input, spline))
        return 0
    return convert(args, spline)


def import_pov(path: str, output: str | None) -> int:
    """``--from-pov``: one profile CSV and one ``<shape>`` snippet per
    ``lathe``/``sor`` block, each validated as a profile first."""
    import numpy as np

    from ..profiles import write_profile_csv
    from ..profiles.pov import lathe_snippet, read_pov_blocks
    from ..profiles.text import PointLabels
    from ..surfaces import make_surface
    from .common import output_folder

    blocks = read_pov_blocks(path)
    if not blocks:
        raise CliError(f"{path}: no literal lathe or sor block found")
    folder = output_folder(output if output is not None else os.path.dirname(path) or ".")
    for block in blocks:
        source = f"{block.where}: {block.object} '{block.name}'"
        labels = PointLabels.counting(source, len(block.points))
        make_surface(block.kind, block.points, np.zeros(len(block.points), bool), labels, source,
                     open_sheet=block.open_sheet)
        csv = write_profile_csv(os.path.join(folder, f"{block.name}.csv"), block.points,
                                header=f"{block.object} '{block.name}' of {block.where}",
                                options={"kind": block.kind, "open": block.open_sheet})
        xml = os.path.join(folder, f"{block.name}.xml")
        with open(xml, "w", encoding="utf-8") as f:
            f.write(lathe_snippet(block, os.path.basename(csv)))
        form = "open sheet" if block.open_sheet else "solid"
        print(f"{block.where}: {block.object} '{block.name}': {block.kind}, {len(block.points)} points, "
              f"{form} -> {csv}, {xml}")
        for note in block.notes:
            print(f"  note: {note}", file=sys.stderr)
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_command("lathe-profile", build_parser(), check_profile, argv)


if __name__ == "__main__":
    sys.exit(main())
