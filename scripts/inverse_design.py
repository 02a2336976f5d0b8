"""Inverse design: recover a hidden lathe profile from two rendered views.

Renders the hidden profile (a 12-point polyline glass or an 8-control-point
B-spline vase, ``lathe_shape.tools.inverse.HIDDEN_PROFILES``) from two views,
then starts from a cylinder with as many points and optimises the points
with ``lathe_prb`` gradients (Adam, smoothness and even-spacing
regularisers, projection onto valid profiles). Prints the loss and the profile RMS error (relative to the
height) per iteration; writes convergence.png and the target, before and
after images of every view to -o/--output.

    python scripts/inverse_design.py [--kind polyline|bspline] [--iterations 60] [--resolution 32x32]
                                     [--spp 16] [--learning-rate 0.02] [--smoothness 3e-3]
                                     [--spacing 3e-3] [--seed 0] [-o inverse_out]
                                     [--variant llvm_ad_rgb]

The views are square: ``--resolution`` is ``NxN`` or ``N``.
"""

from __future__ import annotations

import argparse
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
    parser.add_argument("--kind", choices=sorted(HIDDEN_PROFILES), default="polyline",
                        help="profile parameterisation (default: polyline)")
    parser.add_argument("--iterations", type=int, default=60, help="optimisation steps (default: 60)")
    add_render_options(parser, spp_default=16, resolution_default="32x32", defines=False,
                       seed_help="seed of the pixel samples (default: 0)")
    parser.add_argument("--learning-rate", type=float, default=0.02,
                        help="Adam step size at the start, decaying tenfold (default: 0.02)")
    parser.add_argument("--smoothness", type=float, default=3e-3,
                        help="second-difference regulariser weight (decays hundredfold; default: 3e-3)")
    parser.add_argument("--spacing", type=float, default=3e-3,
                        help="even-spacing regulariser weight (decays hundredfold; default: 3e-3)")
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


def inverse_design(args: argparse.Namespace) -> int:
    check_at_least("--iterations", args.iterations, 1)
    check_at_least("--spp", args.spp, 1)
    side = square_resolution(args.resolution)
    select_variant(args.variant)
    out = output_folder(args.output)

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
