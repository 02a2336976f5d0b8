#!/usr/bin/env python3
"""The paper's two open problems (docs/method.md, end), answered with data.

    python scripts/open_problems.py                 # 128x128, 16 spp
    python scripts/open_problems.py --quick         # 32x32, 2 spp, fewer counts (smoke run)
    python scripts/open_problems.py -o out/open --resolution 192x192 --spp 32

(a) *How does image quality depend on the number of segments?* For the fig.
8b glass (an exact B-spline) and the arc-built fig. 9 glass, fig. 10a cup and
fig. 10b bottle (``scenes/paper/figures.json``), polylines with N segments
are placed on the exact curve by several rules and rendered with
``lathe_path``; the image error is the relative mean absolute difference
(:func:`lathe_shape.tools.images.relative_error`) to the exact object
rendered with the *same* seed and spp (the noise is correlated, so the
difference is the geometry's). Rules: ``uniform`` (equal steps of the spline
parameter for the B-spline, equal arc length for the arc objects: no care),
``adaptive`` (:func:`lathe_shape.profiles.bspline.to_polyline`
``'adaptive'``: equal turning angle), ``arc-equal`` (the arc objects' own
arcs divided equally, docs/method.md section 2.3), and the two rules of (b).

(b) *Which polyline is optimal for a given curve?* The error proxy ``E = sum_i
L_i dtheta_i^2`` and the rules ``kappa^2/3`` (points at equal steps of ``int
kappa^(2/3) ds``, E-optimal) and ``greedy`` (halve the piece with the largest
``L dtheta^2``) are explained in :mod:`lathe_shape.validation.placement`. The
proxy is checked against the image error (rank correlation over all
renders), and the table lists the segments each rule needs to reach the
image error of the uniform polyline with 31 segments (fig. 8a's count).

Writes ``open_problems.png`` (error vs N per object, log-log) and
``open_problems.txt`` (the tables) into the output folder.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from lathe_shape.cli import common as cli

PROG = "open_problems.py"

#: Renders a figure's scene with a profile file (None: its own) -> image.
Render = Callable[[str, "str | None"], np.ndarray]


def study_bspline(paper, render: Render, counts: list[int], tmp: Path) -> dict:
    """Error and proxy of every rule and count on the fig. 8b B-spline glass."""
    from lathe_shape.profiles import bspline as bs
    from lathe_shape.profiles import write_profile_csv
    from lathe_shape.tools.images import relative_error
    from lathe_shape.validation import placement as pl
    from lathe_shape.validation.paper import glass_control_points

    figure = paper.open_problems["bspline"]["figure"]
    exact = render(figure, None)
    controls = glass_control_points(paper)
    dense, joints = pl.dense_bspline(controls)
    s, th = pl.turning(dense)
    seg = bs.bspline_segments(controls, "glass")
    none = np.array([], dtype=int)
    table: dict[str, list[tuple[int, float, float]]] = {}
    for n in counts:
        polylines = {
            "uniform": bs.to_polyline(seg, n + 1, "uniform"),
            "adaptive": bs.to_polyline(seg, n + 1, "adaptive"),
            "kappa^2/3": dense[pl.rule_k23(s, th, n, none)],
            "greedy": dense[pl.rule_greedy(s, th, n, joints)],
        }
        for rule, pts in polylines.items():
            csv = write_profile_csv(tmp / f"glass_{rule.replace('^2/3', '23')}_{n}.csv", pts,
                                    np.zeros(len(pts), bool))
            error = relative_error(render(figure, csv), exact)
            idx = np.unique(pl.nearest_indices(dense, pts))
            table.setdefault(rule, []).append((len(pts) - 1, error, pl.proxy(idx, s, th)))
    return table


def study_arcs(paper, render: Render, figure: str, name: str, steps: list[float], tmp: Path) -> dict:
    """Error and proxy of the arc-equal, uniform and kappa^2/3 rules on an
    arc-built figure, at the segment counts of the arc steps ``steps``."""
    from lathe_shape.profiles import build_from_spec, spec_with_step, write_profile_csv
    from lathe_shape.tools.images import relative_error
    from lathe_shape.validation import placement as pl
    from lathe_shape.validation.paper import arc_spec

    spec = arc_spec(paper, figure)
    exact = render(figure, paper.references[name].profile_file)
    dense, dense_sharp, _ = pl.dense_arcs(spec)
    s, th = pl.turning(dense)
    must = np.flatnonzero(dense_sharp)
    table: dict[str, list[tuple[int, float, float]]] = {}
    for step in steps:
        pts, sharp = build_from_spec(spec_with_step(spec, step))
        n = len(pts) - 1
        csv = write_profile_csv(tmp / f"{name}_arc_{step:g}.csv", pts, sharp)
        error = relative_error(render(figure, csv), exact)
        idx = np.unique(pl.nearest_indices(dense, pts))
        table.setdefault("arc-equal", []).append((n, error, pl.proxy(idx, s, th)))
        rules = {"uniform": pl.rule_uniform(s, n, must), "kappa^2/3": pl.rule_k23(s, th, n, must)}
        for rule, idx in rules.items():
            csv = write_profile_csv(tmp / f"{name}_{rule.replace('^2/3', '23')}_{n}.csv", dense[idx],
                                    dense_sharp[idx])
            table.setdefault(rule, []).append((len(idx) - 1, relative_error(render(figure, csv), exact),
                                               pl.proxy(idx, s, th)))
    return table


def study(args: argparse.Namespace) -> int:
    from lathe_shape.cli.common import select_variant
    from lathe_shape.validation.paper import load_paper, render_exact, render_size
    from lathe_shape.validation.placement import error_report, plot_errors

    select_variant(args.variant)
    cli.check_at_least("--spp", args.spp, 1)
    cli.check_between("--seed", args.seed, 0, cli.UINT32_MAX)
    size = render_size(args.resolution, 32 if args.quick else 128)
    spp = args.spp or (2 if args.quick else 16)
    counts = [16, 31, 64] if args.quick else [16, 24, 31, 42, 64, 96, 128, 192]
    steps = [15.0, 7.5] if args.quick else [30.0, 20.0, 15.0, 10.0, 7.5, 5.0, 3.0, 2.0]
    out = cli.output_folder(args.output)
    defines = cli.parse_defines(args.defines)
    paper = load_paper()
    start = time.perf_counter()
    print(f"{size[0]}x{size[1]}, {spp} spp, seed {args.seed} (exact references use the same seed and spp)")

    def render(figure: str, profile_file: str | None) -> np.ndarray:
        return render_exact(paper.scene(figure), spp, args.seed, size, defines, profile_file=profile_file)[0]

    with tempfile.TemporaryDirectory(prefix="open_problems_") as folder:
        tmp = Path(folder)
        results = {paper.open_problems["bspline"]["label"]: study_bspline(paper, render, counts, tmp)}
        for entry in paper.open_problems["arcs"]:
            figure, name = entry["figure"], entry["name"]
            results[f"{name} (fig. {figure[3:]}, arcs)"] = study_arcs(paper, render, figure, name, steps, tmp)
            print(f"  {name} done ({time.perf_counter() - start:.0f} s)", flush=True)
    text = "\n".join(error_report(results))
    print(text)
    with open(os.path.join(out, "open_problems.txt"), "w", encoding="utf-8") as f:
        f.write(text + "\n")
    plot_errors(results, os.path.join(out, "open_problems.png"))
    print(f"wrote {os.path.join(out, 'open_problems.png')}, {os.path.join(out, 'open_problems.txt')} "
          f"in {time.perf_counter() - start:.1f} s")
    return 0


def main(argv: list[str] | None = None) -> int:
    from lathe_shape.validation.paper import script_parser

    parser = script_parser(PROG, __doc__, os.path.join("out", "open_problems"),
                           "open_problems.txt and open_problems.png", seed=3,
                           quick="32x32, 2 spp, fewer segment counts (a smoke run)",
                           defaults="128x128, 16 spp")
    return cli.run_command(PROG, parser, study, argv)


if __name__ == "__main__":
    sys.exit(main())
