#!/usr/bin/env python3
"""Render a lathe scene with POV-Ray 3.7 and with lathe_whitted, and compare.

    python scripts/compare_povray.py scenes/wine_glass.xml --resolution 512x512 --spp 16

The scene is written as a POV-Ray scene (``scene.pov`` in the output folder;
the lathe as ``lathe { linear_spline ... }``, a B-spline lathe as
``bezier_spline`` after an exact conversion; see
:mod:`lathe_shape.tools.povray_export` for the axis conversion and how
lights and materials are matched), rendered by ``povray`` and by Mitsuba
with ``lathe_whitted`` at the same resolution, antialiasing (``--spp`` is
rounded to a square, POV-Ray's n x n grid) and number of threads. It prints
both times, the image difference, and last a line ``povray 1.23 s,
lathe_whitted 0.45 s, ratio 0.37x``; it writes both images (EXR, PNG) and a
side-by-side sheet ``sheet.png``.
"""

from __future__ import annotations

import argparse
import os
import sys

from lathe_shape.cli import common as cli

PROG = "compare_povray.py"


def compare(args: argparse.Namespace) -> int:
    from lathe_shape.tools.images import write_images
    from lathe_shape.tools.povray_export import PovExportError
    from lathe_shape.validation.paper import write_sheet
    from lathe_shape.validation.povray_compare import aa_grid, compare_scene

    cli.check_render_options(args)
    cli.check_at_least("--max-depth", args.max_depth, 2)  # (1 renders emitters alone: black)
    scene = cli.open_scene(args.scene, args.variant, args.defines, args.resolution)
    out = cli.output_folder(args.output)
    try:
        result = compare_scene(scene, out, args.spp, args.max_depth, args.seed)
    except PovExportError as error:
        raise PovExportError(f"{args.scene}: {error}") from None
    grid = aa_grid(args.spp)
    write_images(os.path.join(out, "povray"), result.povray)
    write_images(os.path.join(out, "lathe_whitted"), result.whitted)
    tiles = [("POV-Ray 3.7", result.povray), ("lathe_whitted", result.whitted)]
    write_sheet(os.path.join(out, "sheet.png"), tiles, (0.3, 0.2, 0.7, 0.6))
    errors = result.errors
    height, width = result.povray.shape[:2]
    print(f"{args.scene}: {width}x{height}, {grid}x{grid} samples per pixel, {os.cpu_count()} threads; "
          f"wrote {out}")
    print(f"difference: rel. MAE {errors['rel_mae']:.4f}, rel. RMSE {errors['rel_rmse']:.4f}, "
          f"bias {errors['bias']:+.4f}")
    print(f"lathe_whitted's first render (kernel compilation or cache load included): "
          f"{result.whitted_first_seconds:.2f} s")
    print(result.summary())
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog=PROG, description=__doc__.splitlines()[0])
    parser.add_argument("scene", help="Mitsuba scene file (XML)")
    cli.add_output_option(parser, default=os.path.join("out", "povray"), what="scene.pov, images, sheet")
    cli.add_render_options(parser, spp_default=16, spp_help="16; rounded to n*n, POV-Ray's n x n grid")
    parser.add_argument("--max-depth", type=int, default=10,
                        help="lathe_whitted max_depth, at least 2; POV-Ray's max_trace_level is one "
                             "less, as it does not count the segment to the light (default: 10)")
    return cli.run_command(PROG, parser, compare, argv)


if __name__ == "__main__":
    sys.exit(main())
