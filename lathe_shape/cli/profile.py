"""``lathe-profile``: check a profile file, turn a curve profile (any kind
but ``polyline``) into a polyline profile of N points, or import the
``lathe``/``sor`` objects of a POV-Ray scene (:mod:`..profiles.pov_sdl`
reads the scene; one line per object; exit status 1 if any failed).

Examples::

    lathe-profile scenes/wine_glass.csv                                  # validate + summary
    lathe-profile glass.csv --kind bspline --to-polyline 32              # CSV on stdout
    lathe-profile glass.csv --kind bspline --to-polyline 32 -o out       # writes out/glass_32.csv
    lathe-profile cup.csv --kind bezier --open                           # an open sheet
    lathe-profile --from-pov vases.pov -o profiles                       # NAME.csv + NAME.xml per object
    lathe-profile --from-pov vases.pov -o profiles --scene vases.xml     # + a scene for lathe-render

A CSV's ``# kind: NAME`` and ``# open: true`` lines (as ``--from-pov``
writes them) stand for ``--kind`` and ``--open``.
"""

from __future__ import annotations

import argparse
import os
import sys

from .common import CliError, run_command

__all__ = ["MAX_POLYLINE_POINTS", "main", "build_parser", "profile_kinds"]


def profile_kinds() -> dict:
    """The ``--kind`` values and their profile kinds' records (the kinds'
    ``cli_name``, :data:`lathe_shape.surfaces.KINDS`)."""
    from ..surfaces import KINDS

    return {kind.cli_name: kind for kind in KINDS.values() if kind.cli_name}

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
    parser.add_argument("--kind", choices=tuple(profile_kinds()), default=None,
                        help="how to read the points (default: the CSV's '# kind:' line, else polyline)")
    parser.add_argument("--open", action=argparse.BooleanOptionalAction, default=None,
                        help="the profile is a single open sheet, or (--no-open) the outline of a solid "
                             "(default: the CSV's '# open:' line, else a solid)")
    parser.add_argument("--from-pov", metavar="FILE.pov",
                        help="import every lathe and sor object of a POV-Ray scene (its #declare, "
                             "#if, #while, macros, #include and transforms evaluated): writes "
                             "NAME.csv and a Mitsuba <shape> snippet NAME.xml per object into -o DIR "
                             "(default: next to FILE.pov); one line per object; exit status 1 if "
                             "any object could not be imported")
    parser.add_argument("--scene", metavar="OUT.xml",
                        help="with --from-pov: also write a complete Mitsuba scene (camera, light, "
                             "floor, materials) of the imported objects, for lathe-render")
    parser.add_argument("--declare", action="append", default=[], metavar="NAME=VALUE",
                        help="with --from-pov: a number POV-Ray's scene sees as declared (as "
                             "POV-Ray's Declare=NAME=VALUE, e.g. frame_number=11); repeatable")
    parser.add_argument("--strict-curves", action="store_true",
                        help="with --from-pov: refuse a curve that crosses itself (default: a "
                             "small loop, which POV-Ray renders, is written as a separate closed "
                             "curve, with a warning)")
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
                      open_sheet: bool = False, polyline=None, kind: str = "polyline") -> str:
    """Validate polyline points (unless ``polyline``, the validated profile
    of a kind ``kind`` that runs the polyline kernel, is given); the
    one-line summary."""
    import numpy as np

    from ..profiles import make_profile

    if polyline is None:
        polyline = make_profile(points, sharp, labels, source=path, crease_angle=crease_angle,
                                open_sheet=open_sheet)
    r_max, z_min, z_max = polyline.bounds()
    form = ("open sheet" if open_sheet else
            "closed loop" if polyline.closed_loop else "both ends on the axis")
    joints = np.any(polyline.normal_end[:-1] != polyline.normal_start[1:], axis=1)
    # (a closed loop's last segment meets its first: that joint counts too)
    wrap = polyline.closed_loop and bool(np.any(polyline.normal_end[-1] != polyline.normal_start[0]))
    creases = int(np.sum(joints)) + wrap
    return (f"{path}: valid {kind} profile, {len(polyline.points)} points, "
            f"{polyline.segment_count} surface segments, {form}, r <= {r_max:g}, "
            f"z in [{z_min:g}, {z_max:g}], {creases} creases at {crease_angle:g} deg")


def describe_bspline(path: str, spline) -> str:
    """The one-line summary of a validated curve profile (any kind but
    polyline)."""

    from ..profiles.bspline import cubic_ranges, power_coefficients

    # The curve's own extent (bounds() gives the control polygon's for a
    # B-spline, which bounds the curve), round-off at 0 shown as 0
    if hasattr(spline, "segment_controls"):
        coef = power_coefficients(spline.segment_controls)
        r, z = cubic_ranges(coef[:, 0]), cubic_ranges(coef[:, 1])
        extent = float(r[:, 1].max()), float(z[:, 0].min()), float(z[:, 1].max())
    else:  # (sor: its bounds are the curve's, exactly)
        extent = spline.bounds()
    tiny = 1e-12 * max(abs(v) for v in extent)
    r_max, z_min, z_max = (0.0 if abs(v) <= tiny else v for v in extent)
    if spline.kind == "bspline":
        form = "closed periodic" if spline.closed_loop else "solid, ends on the axis"
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
    from ..surfaces import check_curve_points, make_surface

    if (args.input is None) == (args.from_pov is None):
        raise CliError("give a profile file, or --from-pov FILE.pov (not both)")
    if args.from_pov is not None:
        return import_pov(args.from_pov, args.output, scene=args.scene, declares=args.declare,
                          strict_curves=args.strict_curves)
    points, sharp, labels = read_points(args.input)
    kinds = profile_kinds()
    # (an unknown '# kind:' is refused here, naming the file and line, unless --kind overrides it)
    declared = read_profile_options(args.input, None if args.kind else [k.name for k in kinds.values()])
    if args.kind is not None:
        record = kinds[args.kind]
    else:
        name = declared.get("kind", "polyline")
        record = next(k for k in kinds.values() if k.name == name)
    kind = record.name
    open_sheet = declared.get("open", False) if args.open is None else args.open
    if record.kernel == "polyline":
        if args.to_polyline is not None:
            raise CliError("--to-polyline needs a curve --kind (the input is already a polyline)")
        polyline = None
        if kind != "polyline":
            polyline = make_surface(kind, points, sharp, labels, args.input, args.crease_angle,
                                    open_sheet=open_sheet).profile
        print(describe_polyline(args.input, points, sharp, labels, args.crease_angle, open_sheet,
                                polyline, kind))
        return 0
    if kind == "bspline" and not open_sheet:
        check_curve_points(kind, points, sharp, labels)  # (as the lathe shape does: make_surface)
        spline = make_bspline_profile(points, args.input)
    else:
        spline = make_surface(kind, points, sharp, labels, args.input, open_sheet=open_sheet).profile
    if args.to_polyline is None:
        print(describe_bspline(args.input, spline))
        return 0
    return convert(args, spline)


#: Most placements of one object written (a declared object may be placed
#: by a loop thousands of times).
MAX_PLACEMENTS = 64


def _declares(items: list[str]) -> dict:
    defines = {}
    for item in items:
        name, sep, value = item.partition("=")
        try:
            if not sep or not name.isidentifier():
                raise ValueError
            defines[name] = float(value)
        except ValueError:
            raise CliError(f"--declare {item!r}: expected NAME=NUMBER") from None
    return defines


def import_pov(path: str, output: str | None, scene: str | None = None,
               declares: list[str] | None = None, strict_curves: bool = False) -> int:
    """``--from-pov``: one profile CSV and one ``<shape>`` snippet per
    ``lathe``/``sor`` object, each validated as a profile first; every
    object imports or fails on its own (one line each); 1 if any failed."""
    import numpy as np

    from ..profiles.pov import read_pov_objects, to_world
    from ..profiles.pov_sdl.objects import _singular
    from ..tools.pov_scene import SceneShape, relative_csv, scene_xml
    from .common import output_folder

    if scene is not None and not scene.endswith(".xml"):
        raise CliError(f"--scene {scene}: the scene file must end in .xml")
    blocks, scene_notes = read_pov_objects(path, _declares(declares or []))
    if not blocks:
        for note in scene_notes[:20]:
            print(f"  note: {note}", file=sys.stderr)
        raise CliError(f"{path}: no lathe or sor object found")
    folder = None
    failed = 0
    shapes: list[SceneShape] = []
    for block in blocks:
        head = f"{block.where}: {block.object} '{block.name}'"
        try:
            if block.error is not None:
                raise ValueError(block.error)
            for m in block.transforms or [block.transform]:
                if _singular(m):
                    raise ValueError(f"{block.where}: the {block.object}'s transform in the scene is "
                                     f"singular (a zero scale flattens it; Mitsuba cannot load it)")
            kind, points, loops, notes = _checked_curve(block, strict_curves)
        except (ValueError, RuntimeError) as e:
            reason = str(e)
            if reason.startswith(block.where + ": "):
                reason = reason[len(block.where) + 2:]
            print(f"{head}: not imported: {reason}")
            failed += 1
            continue
        if folder is None:
            folder = output_folder(output if output is not None else os.path.dirname(path) or ".")
        written, shape = _write_object(block, folder, kind, points, loops)
        transforms = block.transforms or [block.transform]
        placed = transforms[:MAX_PLACEMENTS]
        form = "open sheet" if block.open_sheet else "solid"
        more = f", {len(transforms)} placements" if len(transforms) > 1 else ""
        print(f"{head}: {kind}, {len(points)} points, {form}{more} -> {', '.join(written)}")
        if len(transforms) > MAX_PLACEMENTS:
            notes.append(f"placed {len(transforms)} times: the first {MAX_PLACEMENTS} are written")
        for note in block.notes + notes:
            # (on stderr: named, as it may be read apart from the lines above)
            print(f"  note: {head}: {note}", file=sys.stderr)
        for name, csv, k, pts, open_sheet in shape:
            shapes.append(SceneShape(name, csv, k, open_sheet, [to_world(m) for m in placed], pts,
                                     block.material, comment=f"{block.object} '{block.name}' of "
                                                             f"{block.where}"))
    for note in scene_notes[:20]:
        print(f"  note: {note}", file=sys.stderr)
    if len(scene_notes) > 20:
        print(f"  note: ... and {len(scene_notes) - 20} more notes on the scene", file=sys.stderr)
    if scene is not None and shapes:
        scene_folder = os.path.dirname(os.path.abspath(scene))
        os.makedirs(scene_folder, exist_ok=True)
        for s in shapes:
            s.csv = relative_csv(s.csv, scene)
        with open(scene, "w", encoding="utf-8") as f:
            f.write(scene_xml(shapes, path, scene_file=scene))
        print(f"wrote the scene {scene} ({sum(len(s.to_worlds) for s in shapes)} shapes): "
              f"lathe-render {scene}")
    if failed:
        print(f"{path}: {failed} of {len(blocks)} objects not imported", file=sys.stderr)
    del np
    return 1 if failed else 0


def _checked_curve(block, strict_curves: bool):
    """``(kind, points, loops, notes)``: the block's curve validated as a
    profile; a curve crossing itself in a small loop (which POV-Ray renders)
    is split into the rest and the loop (:mod:`..profiles.pov_loops`),
    unless ``strict_curves``. Raises ValueError."""
    import numpy as np

    from ..profiles.pov_loops import remove_small_loops
    from ..profiles.text import PointLabels
    from ..surfaces import make_surface

    def check(kind, points, open_sheet, source):
        labels = PointLabels.counting(source, len(points))
        make_surface(kind, points, np.zeros(len(points), bool), labels, source, open_sheet=open_sheet)

    source = f"{block.where}: {block.object} '{block.name}'"
    try:
        check(block.kind, block.points, block.open_sheet, source)
        return block.kind, block.points, [], []
    except ValueError as e:
        if strict_curves or "intersects itself" not in str(e):
            raise
        first = e
    kind, points, notes, loops = remove_small_loops(block.kind, block.points, source)
    if not notes:
        raise first
    try:
        check(kind, points, block.open_sheet, source)
        for k, loop in enumerate(loops):
            check("bezier", loop, False, f"{source}: loop {k + 1}")
    except ValueError as e:
        raise ValueError(f"{first} (cutting its small loops off did not help: {e})") from None
    return kind, points, loops, [f"warning: {n}" for n in notes]


def _write_object(block, folder: str, kind: str, points, loops):
    """NAME.csv (+ NAME_loopK.csv) and NAME.xml; the files written and the
    (id, csv, kind, points, open) of each profile."""
    from ..profiles import write_profile_csv
    from ..profiles.pov import lathe_snippet

    profiles = [(block.name, kind, points, block.open_sheet)]
    profiles += [(f"{block.name}_loop{k + 1}", "bezier", loop, False) for k, loop in enumerate(loops)]
    written, shapes, snippets = [], [], []
    transforms = (block.transforms or [block.transform])[:MAX_PLACEMENTS]
    for name, k, pts, open_sheet in profiles:
        csv = write_profile_csv(os.path.join(folder, f"{name}.csv"), pts,
                                header=f"{block.object} '{block.name}' of {block.where}",
                                options={"kind": k, "open": open_sheet})
        written.append(csv)
        shapes.append((name, csv, k, pts, open_sheet))
        for j, m in enumerate(transforms):
            snippets.append(lathe_snippet(block, os.path.basename(csv), transform=m,
                                          shape_id=name if j == 0 else f"{name}__{j + 1}", kind=k,
                                          open_sheet=open_sheet))
    xml = os.path.join(folder, f"{block.name}.xml")
    with open(xml, "w", encoding="utf-8") as f:
        f.write("".join(snippets))
    written.append(xml)
    return written, shapes


def main(argv: list[str] | None = None) -> int:
    return run_command("lathe-profile", build_parser(), check_profile, argv)


if __name__ == "__main__":
    sys.exit(main())
