"""``lathe-compare``: render a scene exactly (``lathe_path``) and as the
reference mesh (stock ``path``) with the same seed, and show the difference.

Example::

    lathe-compare scenes/wine_glass.xml -o out/compare --spp 64 --resolution 256x256

Both renders use the same sampler, seed and max_depth, and ``lathe_path``
runs with ``normal_check none``, which draws random numbers exactly as
``path`` does: the two images' noise is correlated and the difference shows
the geometry (exact surface vs tessellation), not the noise. Writes
``exact.exr/png``, ``mesh.exr/png`` and ``diff.png`` (signed luminance
difference mesh - exact in a blue-white-red map with a colour bar) and prints
the relative mean absolute error, the relative RMSE and the largest
difference.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

__all__ = ["main", "build_parser", "diverging_map", "difference_image"]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="lathe-compare",
        description="Render a scene with exact lathes (lathe_path) and as the reference mesh "
                    "(path), same seed, and write both plus a false-colour difference.",
    )
    parser.add_argument("scene", help="Mitsuba XML scene file")
    parser.add_argument("-o", "--output", required=True, help="output folder (created if missing)")
    parser.add_argument("--spp", type=int, help="samples per pixel (default: the scene's sampler)")
    parser.add_argument("--resolution", metavar="WxH", help="override the film resolution, e.g. 256x256")
    parser.add_argument("--mesh-segments", type=int, metavar="N",
                        help="azimuthal steps of the reference mesh (sets -D mesh_segments=N and every "
                             "lathe's own parameter through the scene default)")
    parser.add_argument("--seed", type=int, default=0, help="sampler seed (default: 0)")
    parser.add_argument("--variant", default="llvm_ad_rgb", help="Mitsuba variant (default: llvm_ad_rgb)")
    parser.add_argument(
        "-D", dest="defines", action="append", metavar="KEY=VALUE",
        help="set an XML <default> parameter (repeatable)",
    )
    return parser


def diverging_map(x: np.ndarray) -> np.ndarray:
    """Blue-white-red map of ``x`` in [-1, 1] -> float RGB in [0, 1]
    (linear blend: -1 blue (0.23, 0.30, 0.75), 0 white, +1 red (0.71, 0.02, 0.15))."""
    x = np.clip(np.nan_to_num(np.asarray(x, dtype=np.float64)), -1.0, 1.0)[..., None]
    blue = np.array([0.23, 0.30, 0.75])
    red = np.array([0.71, 0.02, 0.15])
    white = np.ones(3)
    return np.where(x < 0, white + (blue - white) * (-x), white + (red - white) * x)


def _luminance(rgb: np.ndarray) -> np.ndarray:
    return rgb[..., :3] @ np.array([0.2126, 0.7152, 0.0722])


def difference_image(exact: np.ndarray, mesh: np.ndarray, scale: float | None = None,
                     bar: bool = True) -> tuple[np.ndarray, float]:
    """8-bit false-colour image of the luminance difference ``mesh - exact``,
    ``+-scale`` mapping to full red/blue (default: the 99th percentile of
    ``|difference|``), with a colour bar below when ``bar``. Returns
    (uint8 image, scale)."""
    diff = _luminance(mesh) - _luminance(exact)
    if scale is None:
        scale = float(np.percentile(np.abs(diff), 99.0))
    scale = scale if scale > 0 else 1.0
    rgb = diverging_map(diff / scale)
    if bar:
        h, w = diff.shape
        bar_h = max(6, h // 16)
        ramp = np.linspace(-1.0, 1.0, w)[None, :].repeat(bar_h, axis=0)
        rgb = np.concatenate([rgb, np.ones((2, w, 3)), diverging_map(ramp)], axis=0)
        # Ticks at -scale, 0, +scale: dark marks on the bar.
        for x in (0, w // 2, w - 1):
            rgb[h + 2:, x] = 0.0
    return np.round(np.clip(rgb, 0, 1) * 255).astype(np.uint8), scale


def _scene_max_depth(scene) -> int | None:
    """max_depth of the scene's integrator, if it has one."""
    import mitsuba as mi

    integrator = scene.integrator()
    if integrator is None:
        return None
    params = mi.traverse(integrator)
    if "max_depth" in params:
        return int(params["max_depth"])
    for line in str(integrator).splitlines():
        key, sep, value = line.strip().partition("=")
        if sep and key.strip() == "max_depth":
            try:
                return int(value.strip().rstrip(","))
            except ValueError:
                return None
    return None


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    import mitsuba as mi

    from ..tools.images import image_errors, write_exr, write_png
    from ..tools.scenes import SceneError
    from .common import CliError, open_scene, root_message
    from .common import output_folder as check_output_folder

    def fail(message: str) -> int:
        print(f"lathe-compare: error: {message}", file=sys.stderr)
        return 2

    if args.spp is not None and args.spp < 1:
        return fail(f"--spp must be at least 1, got {args.spp}")
    if args.mesh_segments is not None and args.mesh_segments < 3:
        return fail(f"--mesh-segments must be at least 3, got {args.mesh_segments}")
    extra = {} if args.mesh_segments is None else {"mesh_segments": str(args.mesh_segments)}
    try:
        scene = open_scene(args.scene, args.variant, args.defines, args.resolution, extra)
        out = check_output_folder(args.output)
    except (SceneError, CliError) as e:
        return fail(str(e))
    if not scene.sensors():
        return fail(f"{args.scene}: the scene has no sensor")
    lathes = [s for s in scene.shapes() if hasattr(s, "ray_intersect_exact")]
    if not lathes:
        return fail(f"{args.scene}: the scene has no lathe shape to compare")

    sensor = scene.sensors()[0]
    width, height = sensor.film().size()
    spp = args.spp or sensor.sampler().sample_count()
    depth = _scene_max_depth(scene)
    depth = -1 if depth is None else depth
    exact_integrator = mi.load_dict({"type": "lathe_path", "max_depth": depth, "normal_check": "none"})
    mesh_integrator = mi.load_dict({"type": "path", "max_depth": depth})
    print(
        f"lathe-compare: {args.scene} -> {out}\n"
        f"  {width}x{height}, {spp} spp, max_depth {depth}, seed {args.seed}, variant {args.variant}, "
        f"{len(lathes)} lathe(s)",
        flush=True,
    )

    images = {}
    runs = (("exact", "lathe_path", exact_integrator), ("mesh", "path", mesh_integrator))
    for name, kind, integrator in runs:
        start = time.perf_counter()
        try:
            rgb = mi.render(scene, spp=spp, seed=args.seed, integrator=integrator).numpy()
        except RuntimeError as e:
            return fail(root_message(e))
        elapsed = time.perf_counter() - start
        images[name] = rgb
        metadata = {"spp": int(spp), "integrator": kind, "seed": int(args.seed),
                    "variant": args.variant, "scene": os.path.abspath(args.scene),
                    "render_seconds": float(elapsed)}
        write_exr(os.path.join(out, f"{name}.exr"), rgb, metadata)
        write_png(os.path.join(out, f"{name}.png"), rgb)
        print(f"  {name:<5} ({kind}) rendered in {elapsed:.2f} s", flush=True)

    diff_png, scale = difference_image(images["exact"], images["mesh"])
    mi.Bitmap(diff_png, pixel_format=mi.Bitmap.PixelFormat.RGB).write(os.path.join(out, "diff.png"))
    err = image_errors(images["mesh"], images["exact"])
    print(f"  mesh vs exact: relative mean abs error {err['rel_mae']:.4f}, relative RMSE "
          f"{err['rel_rmse']:.4f}, max abs difference {err['max_abs']:.4f}, bias {err['bias']:+.4f}")
    print(f"  diff.png: luminance mesh - exact, blue -{scale:.3g} .. white 0 .. red +{scale:.3g} "
          f"(colour bar below the image)")
    files = ("exact.exr", "exact.png", "mesh.exr", "mesh.png", "diff.png")
    print(f"  wrote {', '.join(os.path.join(out, f) for f in files)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
