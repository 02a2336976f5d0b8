"""Inverse design: recover a hidden lathe profile from two rendered views.

Renders the hidden profile (a 12-point polyline glass or an 8-control-point
B-spline vase, ``lathe_shape.tools.inverse.HIDDEN_PROFILES``; or, with
``--kind hollow``, a clear 17-point hollow wine glass,
``lathe_shape.tools.inverse_glass.HIDDEN_HOLLOW``, three views) from two views,
then starts from a cylinder with as many points and optimises the points
with ``lathe_prb`` gradients (Adam, smoothness and even-spacing
regularisers, projection onto valid profiles). Prints the loss and the profile RMS error (relative to the
height) per iteration; writes convergence.png and the target, before and
after images of every view to -o/--output.

``--kind hollow`` recovers both walls of a clear glass (dielectric, IOR 1.5)
inside a smooth coloured emissive sphere, seen level, from above and from
below, starting from a hollow cylinder, from the three renders and their
silhouettes (the glass black before white: what segmenting the photographs
gives; ``--silhouette-weight`` weighs their loss, 0 leaves them out),
taking back a step that raised the image loss above ``1 + --uphill``
times the lowest so far. It makes one descent from each of ``--starts``
(tumblers whose inside bottom is at those fractions of the height) and
keeps the one whose renders agree best with the hidden glass's at 64x64
pixels and 32 spp, from pixel samples no descent used; the segments that
meet the axis fall towards it by at most ``--axis-slope`` per unit of
radius (no narrow spike along the axis). The kept descent then goes on
for ``--refine-steps`` steps at 64x64 pixels and 64 spp, with new pixel
samples every step and 0.15 times the step size (0: no refinement). It
prints the outer and the inner wall's RMS errors per iteration, and every
descent's end (defaults there: 120 iterations, 32x32, 8 spp, step 0.02,
smoothness 1e-3, silhouette weight 4, uphill 0.1, starts 0.4 0.45 0.5,
axis slope 1, 100 refinement steps).

    python scripts/inverse_design.py [--kind polyline|bspline|hollow] [--iterations 60] [--resolution 32x32]
                                     [--spp 16] [--learning-rate 0.02] [--smoothness 3e-3]
                                     [--spacing 3e-3] [--silhouette-weight 4] [--uphill 0.1]
                                     [--starts 0.4 0.45 0.5] [--axis-slope 1] [--refine-steps 100]
                                     [--seed 0]
                                     [-o inverse_out]
                                     [--variant llvm_ad_rgb]

The views are square: ``--resolution`` is ``NxN`` or ``N``.
"""

from __future__ import annotations

import argparse
import math
import os
import sys

from lathe_shape.cli.common import (
    CliError,
    add_output_option,
    add_render_options,
    check_at_least,
    output_folder,
    parse_resolution,
    run_command,
    select_variant,
)
from lathe_shape.tools.inverse import HIDDEN_PROFILES, plot_convergence, recover_profile, write_result_images

PROG = "inverse_design.py"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog=PROG, description=__doc__.splitlines()[0])
    parser.add_argument("--kind", choices=[*sorted(HIDDEN_PROFILES), "hollow"], default="polyline",
                        help="profile parameterisation, or 'hollow': a clear hollow wine glass, both walls "
                             "(default: polyline)")
    parser.add_argument("--iterations", type=int, default=None,
                        help="optimisation steps (default: 60; hollow: 120)")
    add_render_options(parser, spp_default=None, resolution_default="32x32", defines=False,
                       spp_help="16; hollow: 8",
                       seed_help="seed of the pixel samples (default: 0)")
    parser.add_argument("--learning-rate", type=float, default=0.02,
                        help="Adam step size at the start, decaying tenfold (default: 0.02)")
    parser.add_argument("--smoothness", type=float, default=None,
                        help="second-difference regulariser weight (decays hundredfold; default: 3e-3; "
                             "hollow: 1e-3)")
    parser.add_argument("--spacing", type=float, default=3e-3,
                        help="even-spacing regulariser weight (decays hundredfold; default: 3e-3)")
    parser.add_argument("--silhouette-weight", type=float, default=4.0,
                        help="hollow only: weight of the silhouettes' loss against the renders' (default: 4; "
                             "0: the renders alone)")
    parser.add_argument("--uphill", type=float, default=0.1,
                        help="hollow only: a step that raises the image loss above (1 + this) times the "
                             "lowest so far is taken back (default: 0.1; a negative value: never)")
    parser.add_argument("--starts", type=float, nargs="+", default=None, metavar="FRACTION",
                        help="hollow only: one descent from a tumbler with its inside bottom at each of "
                             "these fractions of the height (0 < f < 1); the one whose renders agree best "
                             "is kept (default: 0.4 0.45 0.5)")
    parser.add_argument("--axis-slope", type=float, default=None,
                        help="hollow only: the segments that meet the axis fall towards it by at most this "
                             "much per unit of radius (default: 1, 45 degrees; a negative value: any slope)")
    parser.add_argument("--refine-steps", type=int, default=None,
                        help="hollow only: steps of the kept descent's refinement at 64x64 pixels, 64 spp, "
                             "new pixel samples every step (default: 100; 0: none)")
    add_output_option(parser, default="inverse_out",
                      what="convergence.png and view_K_{target,before,after}.png")
    return parser


def square_resolution(text: str) -> int:
    """The side of the square views ``--resolution`` asks for (``NxN`` or
    ``N``, at least 8); raises :class:`CliError` otherwise."""
    width, height = parse_resolution(text)
    if width != height:
        raise CliError(f"--resolution must be square (the views are), got {text!r}")
    check_at_least("--resolution", width, 8)
    return width


def hollow_design(args: argparse.Namespace, side: int, out: str) -> int:
    """``--kind hollow``: both walls of the clear wine glass."""
    from lathe_shape.tools.inverse_glass import (
        AXIS_SLOPE,
        HIDDEN_HOLLOW,
        REFINE,
        START_BOTTOMS,
        plot_hollow_convergence,
        recover_hollow,
    )

    starts = tuple(args.starts) if args.starts else START_BOTTOMS
    axis_slope = AXIS_SLOPE if args.axis_slope is None else None if args.axis_slope < 0.0 else args.axis_slope
    steps = REFINE[2] if args.refine_steps is None else args.refine_steps
    refine = (*REFINE[:2], steps) if steps else None
    headers = iter([*(f"descent from a tumbler with its inside bottom at {bottom:g} of the height"
                      for bottom in starts),
                    f"refinement of the kept descent at {REFINE[0]}x{REFINE[0]} pixels, {REFINE[1]} spp"])

    def report(iteration: int, loss: float, errors: tuple[float, float]) -> None:
        if iteration == 0:
            print(next(headers), flush=True)
        print(f"iteration {iteration:4d}  loss {loss:.6f}  profile error outer wall {100 * errors[0]:.3f}%, "
              f"inner wall {100 * errors[1]:.3f}% of height", flush=True)

    target, n_outer = HIDDEN_HOLLOW["wine_glass"]
    result = recover_hollow(target, n_outer, args.iterations, side, args.spp, args.learning_rate,
                            args.smoothness, args.spacing, seed=args.seed,
                            silhouette_weight=args.silhouette_weight,
                            uphill=None if args.uphill < 0.0 else args.uphill, starts=starts,
                            axis_slope=axis_slope, refine=refine, report=report)
    if len(result.descents) > 1:
        for k, (bottom, loss, (outer, inner), _) in enumerate(result.descents):
            kept = "  (kept)" if k == result.kept else ""
            print(f"descent from inside bottom {bottom:g}: validation loss {loss:.6f}, "
                  f"outer wall {100 * outer:.3f}%, inner wall {100 * inner:.3f}% of height{kept}")
    plot_hollow_convergence(result, os.path.join(out, "convergence.png"),
                            f"hollow wine glass: {side}x{side}, {args.spp} spp, three views")
    paths = write_result_images(result, out)
    outer, inner = result.errors[-1]
    print(f"final profile RMS error: outer wall {100 * outer:.3f}%, inner wall {100 * inner:.3f}% of height "
          f"(start {100 * result.start_errors[0]:.3f}%, {100 * result.start_errors[1]:.3f}%); "
          f"valid at every step: {all(result.valid)}; {result.seconds:.1f} s; recovered points "
          f"(the first {n_outer} the outer wall):")
    for r, z in result.points:
        print(f"  {r:.4f} {z:.4f}")
    print(f"wrote {os.path.join(out, 'convergence.png')} and {len(paths)} images")
    return 0


def inverse_design(args: argparse.Namespace) -> int:
    hollow = args.kind == "hollow"
    if args.iterations is None:
        args.iterations = 120 if hollow else 60
    if args.spp is None:
        args.spp = 8 if hollow else 16
    if args.smoothness is None:
        args.smoothness = 1e-3 if hollow else 3e-3
    check_at_least("--iterations", args.iterations, 1)
    if not args.silhouette_weight >= 0.0:
        raise CliError(f"--silhouette-weight must be >= 0, got {args.silhouette_weight:g}")
    if not math.isfinite(args.uphill):
        raise CliError(f"--uphill must be finite, got {args.uphill:g}")
    if args.axis_slope is not None and not math.isfinite(args.axis_slope):
        raise CliError(f"--axis-slope must be finite, got {args.axis_slope:g}")
    for fraction in args.starts or ():
        if not 0.0 < fraction < 1.0:
            raise CliError(f"--starts must be fractions of the height between 0 and 1 (exclusive), "
                           f"got {fraction:g}")
    check_at_least("--refine-steps", args.refine_steps, 0)
    check_at_least("--spp", args.spp, 1)
    side = square_resolution(args.resolution)
    select_variant(args.variant)
    out = output_folder(args.output)
    if hollow:
        return hollow_design(args, side, out)

    def report(iteration: int, loss: float, error: float) -> None:
        print(f"iteration {iteration:4d}  loss {loss:.6f}  profile error {100 * error:.3f}% of height",
              flush=True)

    result = recover_profile(HIDDEN_PROFILES[args.kind], args.kind, args.iterations, side,
                             args.spp, args.learning_rate, args.smoothness, args.spacing, report=report,
                             seed=args.seed)
    plot_convergence(result, os.path.join(out, "convergence.png"),
                     f"{args.kind}: {side}x{side}, {args.spp} spp, two views")
    paths = write_result_images(result, out)
    print(f"final profile RMS error {100 * result.errors[-1]:.3f}% of height; recovered points:")
    for r, z in result.points:
        print(f"  {r:.4f} {z:.4f}")
    print(f"wrote {os.path.join(out, 'convergence.png')} and {len(paths)} images")
    return 0


def main(argv: list[str] | None = None) -> int:
    return run_command(PROG, build_parser(), inverse_design, argv)


if __name__ == "__main__":
    sys.exit(main())
