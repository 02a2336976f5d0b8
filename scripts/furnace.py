"""White-furnace energy table for the `normal_check` policies (eq. 11).

A dielectric glass lathe under a uniform white environment: with nothing lost
every pixel is 1.0. Prints, per policy, the mean over the glass (energy loss =
1 - mean), the pixel standard deviation and the share of speckles (pixels off
by more than 20 %).

    python scripts/furnace.py [--spp 256] [--res 128]
"""

from __future__ import annotations

import argparse

import mitsuba as mi


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--spp", type=int, default=256)
    parser.add_argument("--res", type=int, default=128)
    parser.add_argument("--variant", default="llvm_ad_rgb")
    args = parser.parse_args()
    mi.set_variant(args.variant)
    from lathe_shape.plugin.lathe_path import NORMAL_CHECKS
    from lathe_shape.tools.furnace import furnace_scene, run_furnace

    scene = furnace_scene(resolution=args.res)
    print(f"furnace: {args.res}x{args.res}, {args.spp} spp, max_depth -1, dielectric int_ior 1.5")
    print(f"{'normal_check':<14}{'mean':>10}{'energy loss':>13}{'std':>10}{'speckles':>10}")
    rows = [(policy, {"type": "lathe_path", "max_depth": -1, "normal_check": policy})
            for policy in NORMAL_CHECKS]
    # Baselines: stock `path` on the reference mesh (vertex normals), and the
    # exact lathe with flat normals (nothing can contradict: lossless).
    rows.append(("path (mesh)", {"type": "path", "max_depth": -1}))
    for label, integrator in rows:
        r = run_furnace(scene, spp=args.spp, integrator=mi.load_dict(integrator))
        print(f"{label:<14}{r.mean:>10.4f}{r.loss:>+13.4f}{r.std:>10.4f}{r.speckle:>10.2%}")
    flat = furnace_scene(resolution=args.res, smooth=False)
    r = run_furnace(flat, spp=args.spp, integrator=mi.load_dict({"type": "lathe_path", "max_depth": -1}))
    print(f"{'flat normals':<14}{r.mean:>10.4f}{r.loss:>+13.4f}{r.std:>10.4f}{r.speckle:>10.2%}")


if __name__ == "__main__":
    main()
