"""``lathe-render``: render a Mitsuba scene with lathes to a linear EXR and an
sRGB PNG preview.

Example::

    lathe-render scenes/brandy_bottle.xml -o bottle.exr --spp 64 -D integrator=lathe_path
"""

from __future__ import annotations

import argparse
import os
import sys
import time

__all__ = ["main", "build_parser"]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="lathe-render",
        description="Render a Mitsuba 3 scene containing lathe shapes to EXR (+ PNG preview).",
    )
    parser.add_argument("scene", help="Mitsuba XML scene file")
    parser.add_argument("-o", "--output", help="output EXR file (default: SCENE.exr next to the scene)")
    parser.add_argument("--spp", type=int, help="samples per pixel (default: the scene's sampler)")
    parser.add_argument("--variant", default="llvm_ad_rgb", help="Mitsuba variant (default: llvm_ad_rgb)")
    parser.add_argument("--resolution", metavar="WxH", help="override the film resolution, e.g. 640x480")
    parser.add_argument("--seed", type=int, default=0, help="sampler seed (default: 0)")
    parser.add_argument(
        "-D", dest="defines", action="append", metavar="KEY=VALUE",
        help="set an XML <default> parameter, e.g. -D integrator=lathe_path (repeatable)",
    )
    parser.add_argument("--no-png", action="store_true", help="do not write the PNG preview")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    # Imported here so that --help works without touching the JIT backends.
    import mitsuba as mi

    from ..tools.images import write_exr, write_png
    from ..tools.scenes import (
        SceneError,
        check_output_folder,
        integrator_name,
        open_scene,
        root_message,
        scene_integrator,
    )

    def fail(message: str) -> int:
        print(f"lathe-render: error: {message}", file=sys.stderr)
        return 2

    if args.spp is not None and args.spp < 1:
        return fail(f"--spp must be at least 1, got {args.spp}")
    output = args.output or os.path.splitext(args.scene)[0] + ".exr"
    if not output.lower().endswith(".exr"):
        return fail(f"the output must be an OpenEXR file ending in .exr, got '{output}'")
    try:
        scene = open_scene(args.scene, args.variant, args.defines, args.resolution)
        check_output_folder(os.path.dirname(os.path.abspath(output)))
    except SceneError as e:
        return fail(str(e))
    if not scene.sensors():
        return fail(f"{args.scene}: the scene has no sensor")
    sensor = scene.sensors()[0]
    width, height = sensor.film().size()
    spp = args.spp or sensor.sampler().sample_count()
    integrator = scene_integrator(scene)
    print(
        f"lathe-render: {args.scene} -> {output}\n"
        f"  {width}x{height}, {spp} spp, integrator {integrator_name(integrator)}, "
        f"variant {args.variant}, seed {args.seed}",
        flush=True,
    )
    start = time.perf_counter()
    try:
        rgb = mi.render(scene, spp=spp, seed=args.seed, integrator=integrator).numpy()
    except RuntimeError as e:
        return fail(root_message(e))
    elapsed = time.perf_counter() - start

    metadata = {
        "spp": int(spp),
        "integrator": integrator_name(integrator),
        "variant": args.variant,
        "seed": int(args.seed),
        "scene": os.path.abspath(args.scene),
        "render_seconds": float(elapsed),
    }
    write_exr(output, rgb, metadata)
    written = [output]
    if not args.no_png:
        png = os.path.splitext(output)[0] + ".png"
        write_png(png, rgb)
        written.append(png)
    print(f"  rendered in {elapsed:.2f} s; wrote {', '.join(written)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
