"""Inverse design: recover a hidden lathe profile from two rendered views.

Renders the hidden profile (a 12-point polyline glass or an 8-control-point
B-spline vase, ``lathe_shape.tools.inverse.HIDDEN_PROFILES``) from two views,
then starts from a cylinder with as many points and optimises the points
with ``lathe_prb`` gradients (Adam, smoothness and even-spacing
regularisers, projection onto valid profiles). Prints the loss and the profile RMS error (relative to the
height) per iteration; writes convergence.png and the target, before and
after images of every view to --output.

    python scripts/inverse_design.py [--kind polyline|bspline] [--iterations 60] [--resolution 32]
                                     [--spp 16] [--learning-rate 0.02] [--smoothness 3e-3]
                                     [--spacing 3e-3] [--seed 0] [--output inverse_out]
                                     [--variant llvm_ad_rgb]
"""

from __future__ import annotations

import argparse
import os

from lathe_shape.cli.common import select_variant
from lathe_shape.tools.inverse import HIDDEN_PROFILES, plot_convergence, recover_profile, write_result_images


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--kind", choices=sorted(HIDDEN_PROFILES), default="polyline",
                        help="profile parameterisation (default: polyline)")
    parser.add_argument("--iterations", type=int, default=60, help="optimisation steps (default: 60)")
    parser.add_argument("--resolution", type=int, default=32, help="image width = height (default: 32)")
    parser.add_argument("--spp", type=int, default=16, help="samples per pixel (default: 16)")
    parser.add_argument("--learning-rate", type=float, default=0.02,
                        help="Adam step size at the start, decaying tenfold (default: 0.02)")
    parser.add_argument("--smoothness", type=float, default=3e-3,
                        help="second-difference regulariser weight (decays hundredfold; default: 3e-3)")
    parser.add_argument("--spacing", type=float, default=3e-3,
                        help="even-spacing regulariser weight (decays hundredfold; default: 3e-3)")
    parser.add_argument("--seed", type=int, default=0, help="seed of the pixel samples (default: 0)")
    parser.add_argument("--output", default="inverse_out", help="output directory (default: inverse_out)")
    parser.add_argument("--variant", default="llvm_ad_rgb", help="Mitsuba variant (default: llvm_ad_rgb)")
    args = parser.parse_args(argv)
    if args.iterations < 1 or args.resolution < 8 or args.spp < 1:
        parser.error("--iterations and --spp must be >= 1, --resolution >= 8")
    select_variant(args.variant)
    os.makedirs(args.output, exist_ok=True)

    def report(iteration: int, loss: float, error: float) -> None:
        print(f"iteration {iteration:4d}  loss {loss:.6f}  profile error {100 * error:.3f}% of height",
              flush=True)

    result = recover_profile(HIDDEN_PROFILES[args.kind], args.kind, args.iterations, args.resolution,
                             args.spp, args.learning_rate, args.smoothness, args.spacing, report=report,
                             seed=args.seed)
    plot_convergence(result, os.path.join(args.output, "convergence.png"),
                     f"{args.kind}: {args.resolution}x{args.resolution}, {args.spp} spp, two views")
    paths = write_result_images(result, args.output)
    print(f"final profile RMS error {100 * result.errors[-1]:.3f}% of height; recovered points:")
    for r, z in result.points:
        print(f"  {r:.4f} {z:.4f}")
    print(f"wrote {os.path.join(args.output, 'convergence.png')} and {len(paths)} images")


if __name__ == "__main__":
    main()
