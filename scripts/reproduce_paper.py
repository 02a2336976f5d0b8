#!/usr/bin/env python3
"""Reproduce the paper's figures 8a, 8b, 9, 10a and 10b and measure them.

See docs/method.md, "The paper's results".

    python scripts/reproduce_paper.py                   # 512x512, 64 spp (the scenes' defaults)
    python scripts/reproduce_paper.py --quick           # 48x48, 4 spp: a CI smoke run (< 60 s)
    python scripts/reproduce_paper.py -o out/paper --resolution 256x256 --spp 32
    python scripts/reproduce_paper.py --make            # regenerate the derived profiles of scenes/paper/

The figures, their profiles and references are data: ``scenes/paper/figures.json``
(read by :mod:`lathe_shape.validation.paper`). For every figure the script renders
the scene in ``scenes/paper/`` with the exact ``lathe_whitted`` integrator
(the paper's Whitted ray tracing: Fresnel-weighted reflection and
refraction, point lights, no noise; ``--integrator lathe_path`` path-traces
instead; ``normal_check none``, the scene's max_depth), times it (after one warm-up
render that compiles the kernels), and compares it with an exact,
higher-spp reference of the *same object*:

* figs. 8a, 8b: the exact 12-segment cubic B-spline glass (fig. 8b's curve)
  rendered with ``--ref-spp`` samples (the row for 8b is then the noise
  floor: same geometry, fewer samples);
* figs. 9, 10a, 10b (arc-built polylines): the same arcs divided at 0.5
  degree steps (thousands of segments, i.e. the exact arcs to within 1e-5 of
  their radius), rendered with ``--ref-spp`` samples.

It prints a table (figure, method, segments, time, spline/polyline time
ratio, relative mean absolute error and RMSE against the reference,
:func:`lathe_shape.tools.images.image_errors`) and writes ``figNN.exr/png``,
the references and ``sheet_fig8a_8b_9.png`` (8a, 8b and 9 side by side, full
and a 3x zoom on the bowl, where the careless polyline distorts the
checkered floor) into the output folder.

The profiles: fig. 8b's glass is a hand-placed open B-spline (11 control
points, 12 segments, ``glass_bspline.csv``); fig. 8a samples it uniformly in
the spline parameter (32 points, 31 segments, no care); fig. 9 is a wine
glass built from an arc spec (:mod:`lathe_shape.profiles.arcs`: arcs divided
equally, concentric inner wall, 42 segments), 10a a sundae cup (58) and 10b
a brandy bottle (86), built the same way. ``--make`` rewrites the derived
profile files (deterministic).
"""

from __future__ import annotations

import argparse
import os
import sys
import time

from lathe_shape.cli import common as cli

PROG = "reproduce_paper.py"


def make_profiles(paper) -> int:
    """--make: rewrite the derived profiles, check the segment counts."""
    from lathe_shape.validation.paper import segment_counts, write_derived_profiles

    write_derived_profiles(paper)
    counts = segment_counts(paper)
    for name, figure in paper.figures.items():
        print(f"{name}: {counts[name]} segments (expected {figure.segments})")
    return 0 if all(counts[name] == f.segments for name, f in paper.figures.items()) else 1


def render_all(paper, args, out: str, size, spp: int, ref_spp: int) -> tuple[dict, dict, dict]:
    """Every figure (timed, after a warm-up) and every reference, written to ``out``."""
    from lathe_shape.tools.images import write_exr, write_png
    from lathe_shape.validation.paper import render_exact

    defines = cli.parse_defines(args.defines)
    images, times, references = {}, {}, {}
    for name in paper.figures:
        image, seconds = render_exact(paper.scene(name), spp, args.seed, size, defines, warm=True,
                                      integrator=args.integrator)
        images[name], times[name] = image, seconds
        write_exr(os.path.join(out, f"{name}.exr"), image, {"spp": spp, "seconds": seconds})
        write_png(os.path.join(out, f"{name}.png"), image)
        print(f"  rendered {name} in {seconds:.2f} s", flush=True)
    for name in sorted(paper.references):
        ref = paper.references[name]
        image, _ = render_exact(paper.scene(ref.figure), ref_spp, (args.seed + 1) % 2**32, size, defines,
                                profile_file=ref.profile_file, integrator=args.integrator)
        references[name] = image
        if not image[..., :3].any():  # (a zero error against a black image says nothing)
            print(f"  warning: reference {name} is black (max_depth too small to reach a light?): "
                  "its errors say nothing", file=sys.stderr, flush=True)
        write_exr(os.path.join(out, f"reference_{name}.exr"), image, {"spp": ref_spp})
        write_png(os.path.join(out, f"reference_{name}.png"), image)
    return images, times, references


def table_rows(paper, counts, images, times, references, ref_spp: int) -> list[str]:
    """The table: header, rule, one row per figure."""
    from lathe_shape.tools.images import image_errors

    header = (f"{'figure':<8}{'object':<17}{'method':<10}{'segments':>9}{'time [s]':>10}"
              f"{'ratio':>7}{'rel. MAE':>10}{'rel. RMSE':>11}  {'reference':<34}{'paper time':>11}")
    rows = [header, "-" * len(header)]
    for name, fig in paper.figures.items():
        errors = image_errors(images[name], references[fig.reference])
        ratio = f"{times['fig8b'] / times['fig8a']:.1f}x" if name == "fig8b" else ""
        ref_text = f"{paper.references[fig.reference].text}, {ref_spp} spp"
        rows.append(f"{name:<8}{fig.title:<17}{fig.method:<10}{counts[name]:>9}{times[name]:>10.2f}"
                    f"{ratio:>7}{errors['rel_mae']:>10.4f}{errors['rel_rmse']:>11.4f}  {ref_text:<34}"
                    f"{fig.paper_time:>11}")
    return rows


def reproduce(args: argparse.Namespace) -> int:
    from lathe_shape.cli.common import select_variant
    from lathe_shape.validation.paper import load_paper, render_size, segment_counts, write_sheet

    select_variant(args.variant)
    paper = load_paper()
    if args.make:
        return make_profiles(paper)
    cli.check_at_least("--spp", args.spp, 1)
    cli.check_at_least("--ref-spp", args.ref_spp, 1)
    cli.check_between("--seed", args.seed, 0, cli.UINT32_MAX)
    size = render_size(args.resolution, 48 if args.quick else 512)
    spp = args.spp or (4 if args.quick else 64)
    ref_spp = args.ref_spp or (16 if args.quick else 4 * spp)
    out = cli.output_folder(args.output)
    counts = segment_counts(paper)
    start = time.perf_counter()
    print(f"{size[0]}x{size[1]}, {spp} spp (references {ref_spp} spp), {args.integrator} normal_check none, "
          f"variant {args.variant}, seed {args.seed}", flush=True)
    images, times, references = render_all(paper, args, out, size, spp, ref_spp)
    rows = table_rows(paper, counts, images, times, references, ref_spp)
    print("\n".join(rows), flush=True)
    print(f"spline/polyline time ratio (8b / 8a): {times['fig8b'] / times['fig8a']:.1f}x "
          f"(paper: intersection ~18x, total ~20x)")
    with open(os.path.join(out, "table.txt"), "w", encoding="utf-8") as f:
        f.write(rows[0] + "\n" + "\n".join(rows[2:]) + "\n")
    sheet = paper.sheet
    write_sheet(os.path.join(out, sheet["file"]), [(label, images[name]) for name, label in sheet["tiles"]],
                tuple(sheet["zoom"]))
    print(f"wrote {out} in {time.perf_counter() - start:.1f} s")
    return 0


def main(argv: list[str] | None = None) -> int:
    from lathe_shape.validation.paper import PAPER_INTEGRATORS, script_parser

    parser = script_parser(PROG, __doc__, os.path.join("out", "paper"), "figures, references, table, sheet",
                           seed=7, quick="48x48, 4 spp, references 16 spp (a CI smoke run)",
                           defaults="512x512, 64 spp (the scenes' defaults), references 4x the spp")
    parser.add_argument("--ref-spp", type=int, help="reference spp (default 4x --spp, quick 16)")
    parser.add_argument("--make", action="store_true", help="regenerate the derived profiles and exit")
    parser.add_argument("--integrator", choices=PAPER_INTEGRATORS, default=PAPER_INTEGRATORS[0],
                        help="lathe_whitted: the paper's Whitted ray tracing, noise-free (default); "
                             "lathe_path: path tracing")
    return cli.run_command(PROG, parser, reproduce, argv)


if __name__ == "__main__":
    sys.exit(main())
