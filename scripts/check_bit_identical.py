"""Reference renders for refactors that must not change any image.

    .venv/bin/python scripts/check_bit_identical.py save     # before the change
    .venv/bin/python scripts/check_bit_identical.py compare  # after it: bit for bit

Renders scenes/wine_glass.xml, scenes/brandy_bottle.xml and
scenes/sundae_cup.xml with ``lathe_path`` (and the wine glass with
``lathe_whitted``, ``lathe_prb`` and ``lathe_volpath``) at a fixed seed on
one Dr.Jit thread (the gaussian filter's splats are accumulated in thread
order, so two-thread renders are not bit-reproducible), and saves or
compares the float arrays in ``--folder`` (default /tmp/house_ref).
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))

#: (name, scene file, integrator, res, spp)
RENDERS = (
    ("wine_glass_path", "scenes/wine_glass.xml", "lathe_path", 128, 16),
    ("brandy_bottle_path", "scenes/brandy_bottle.xml", "lathe_path", 128, 16),
    ("sundae_cup_path", "scenes/sundae_cup.xml", "lathe_path", 128, 16),
    ("wine_glass_whitted", "scenes/wine_glass.xml", "lathe_whitted", 64, 4),
    ("wine_glass_prb", "scenes/wine_glass.xml", "lathe_prb", 64, 4),
    ("wine_glass_volpath", "scenes/wine_glass.xml", "lathe_volpath", 64, 4),
)


def render_all(only: list[str] | None) -> dict[str, np.ndarray]:
    import drjit as dr
    import mitsuba as mi

    mi.set_variant("llvm_ad_rgb")
    import lathe_shape  # noqa: F401 (registers the plugins)

    dr.set_thread_count(1)
    images = {}
    for name, path, integrator, res, spp in RENDERS:
        if only and name not in only:
            continue
        start = time.perf_counter()
        scene = mi.load_file(os.path.join(ROOT, path), integrator=integrator, res=str(res), spp=str(spp))
        image = mi.render(scene, seed=7, spp=spp)
        images[name] = np.array(image, dtype=np.float32)
        print(f"{name}: {time.perf_counter() - start:.1f} s", flush=True)
    return images


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("mode", choices=("save", "compare"))
    parser.add_argument("--folder", default="/tmp/house_ref")
    parser.add_argument("--only", nargs="*", help="names of the renders to do (default: all)")
    args = parser.parse_args(argv)
    images = render_all(args.only)
    if args.mode == "save":
        os.makedirs(args.folder, exist_ok=True)
        for name, image in images.items():
            np.save(os.path.join(args.folder, name + ".npy"), image)
        print(f"saved {len(images)} renders in {args.folder}")
        return 0
    failed = 0
    for name, image in images.items():
        reference = np.load(os.path.join(args.folder, name + ".npy"))
        same = reference.shape == image.shape and reference.tobytes() == image.tobytes()
        if not same:
            failed += 1
            diff = np.abs(reference - image).max() if reference.shape == image.shape else "shape"
            print(f"{name}: DIFFERS (max abs difference {diff})")
        else:
            print(f"{name}: bit-identical")
    print("all bit-identical" if not failed else f"{failed} of {len(images)} differ")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
