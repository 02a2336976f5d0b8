"""Measurements of the light-traced caustics of ``lathe_path`` and, in
scenes with media, ``lathe_volpath`` (the library behind
``scripts/bench_caustics.py``).

For each scene: a reference rendered by the plain integrator
(``caustics=false``) at many samples per pixel, then plain and caustic
renders at several sample counts, timed as medians of interleaved runs with
warm kernels, and their relative mean absolute error (luminance) against the
reference on these regions:

* the **caustic region**: pixels seen directly on a surface that is not a
  lathe, where the caustic paths (light -> glass -> surface, traced from the
  light alone) carry at least 10% of the reference;
* the **glass pixels**: pixels whose camera ray first meets a lathe, and
  two parts of them: those where the caustic paths (light -> glass ->
  surface, seen through the glass along a solved camera chain) carry at
  least 10% of the reference (``glass_caustic``), and the others
  (``glass_other``: little or no caustic seen there, so the caustic
  renders reach plain's error there in about their cost per sample);
* the **whole image**.

Printed: the error and time of each run; the time the caustic renders need to
reach plain ``lathe_path``'s error at ``--target-spp`` in the caustic region
(interpolated with error ~ 1/sqrt(time) from the nearest measured run) as a
fraction of plain's time, with its lowest and highest over the rounds (each
round's own runs); the same on the other regions; and, with
``--unbiased SPP``, the mean of a caustic render at that spp against the
reference on each region; and the camera-chain solver's success rate
(:func:`chain_solve_rate`).
"""

from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time

import drjit as dr
import mitsuba as mi
import numpy as np

from ..plugin.params import CAUSTIC_CAMERA_CHAINS, CAUSTIC_PATHS
from .bench import square_side

__all__ = ["REGION_NAMES", "SCENES", "bench_parser", "caustic_image", "chain_solve_rate", "glass_mask",
           "regions", "run_bench", "split_regions", "time_ratio"]

#: The benchmark's scenes: name -> (XML path under the repository, edit of
#: its text or None).
SCENES = {
    "bottle": ("scenes/brandy_bottle.xml", None),
    "wine_glass": ("scenes/wine_glass.xml", None),
    "sundae_cup": ("scenes/sundae_cup.xml", None),
    # The paper's B-spline glass (scenes/paper/fig8b.xml lights it with point
    # lights, whose caustics plain path tracing cannot render) under the
    # wine glass scene's soft box
    "paper_bspline": ("scenes/wine_glass.xml", "bspline"),
    # POV-Ray's curve kinds, imported: a catmull_rom goblet (thindielectric),
    # a tinted sor bottle (dielectric), a bezier vase and an open bezier cup
    "pov_samples": ("scenes/pov_samples/pov_samples.xml", None),
    # Media (lathe_volpath, eq. 44): the wine glass filled with red wine, and
    # the brandy bottle in green glass that absorbs (the tests' green bottle)
    "wine_glass_filled": ("scenes/wine_glass_filled.xml", None),
    "green_bottle": ("scenes/brandy_bottle.xml", "green"),
    # ... and the paper's B-spline glass in the same green glass (the
    # degree-6 kernel under eq. 44)
    "green_bspline": ("scenes/wine_glass.xml", "green_bspline"),
}

#: The scenes with media.
MEDIA_SCENES = ("wine_glass_filled", "green_bottle", "green_bspline")

#: The green bottle's glass: absorbs blue most, green least.
GREEN_GLASS = ('<medium type="homogeneous" name="interior"><rgb name="sigma_t" value="0.05, 0.02, 0.3"/>'
               '<float name="albedo" value="0"/></medium>')


def _green_edit(text: str, path: str, tag: str = '<shape type="lathe" id="brandy_bottle">') -> str:
    """An edit of scenes/brandy_bottle.xml (or of the scene whose lathe
    opens with ``tag``) that fills the lathe's glass with
    :data:`GREEN_GLASS`."""
    if tag not in text:
        raise RuntimeError(f"{path}: the lathe's shape tag {tag} was not found")
    return text.replace(tag, tag + GREEN_GLASS)


def integrator_type(scene: mi.Scene) -> str:
    """``lathe_volpath`` for a scene with media, else ``lathe_path``."""
    media = any(shape.interior_medium() is not None or shape.exterior_medium() is not None
                for shape in scene.shapes())
    return "lathe_volpath" if media else "lathe_path"


def _bspline_edit(root: str):
    """An edit of scenes/wine_glass.xml that puts the paper's B-spline
    glass in place of the wine glass."""
    profile = os.path.join(root, "scenes", "paper", "glass_bspline.csv")

    def edit(text: str, path: str) -> str:
        text = text.replace('<string name="filename" value="wine_glass.csv"/>',
                            f'<string name="filename" value="{profile}"/>\n'
                            '        <string name="kind" value="bspline"/>')
        if profile not in text:
            raise RuntimeError(f"{path}: the wine glass's profile line was not found to replace")
        return text
    return edit


def load(name: str, root: str, resolution: int) -> mi.Scene:
    """The benchmark scene ``name`` at ``resolution`` squared."""
    from ..tools.scenes import load_scene

    path, edit = SCENES[name]
    bspline = _bspline_edit(root)

    def green_bspline(text: str, path: str) -> str:
        return _green_edit(bspline(text, path), path, '<shape type="lathe" id="wine_glass">')
    edits = {"bspline": bspline, "green": _green_edit, "green_bspline": green_bspline, None: None}
    kind = "lathe_volpath" if name in MEDIA_SCENES else "lathe_path"
    return load_scene(os.path.join(root, path), {"integrator": kind}, (resolution, resolution),
                      edit=edits[edit])


def glass_mask(scene: mi.Scene) -> np.ndarray:
    """(H, W) bool: pixels whose centre ray first meets an exact lathe."""
    from .furnace import first_hit_mask

    return first_hit_mask(scene)


def caustic_image(scene: mi.Scene, per_pixel: int, seed: int = 7) -> np.ndarray:
    """(H, W, 3): the caustic paths alone (light -> specular chain ->
    surface seen by the camera), traced from the lights with weight 1."""
    integrator = mi.load_dict({"type": integrator_type(scene), "max_depth": 16})
    sensor = scene.sensors()[0]
    tracer, why = integrator.caustic_setup(scene, sensor)
    if tracer is None:
        raise RuntimeError(f"no caustic paths to trace: {why}")
    film = sensor.film()
    count = per_pixel * int(film.crop_size().x) * int(film.crop_size().y)
    return np.array(tracer.render(scene, integrator.geometry(scene), sensor, seed, count,
                                  mi.Float(float("inf"))))


def path_integrator(caustics: bool, caustic_paths: float = CAUSTIC_PATHS,
                    camera_chains: float = CAUSTIC_CAMERA_CHAINS, kind: str = "lathe_path") -> mi.Integrator:
    """``kind`` (``lathe_path`` or ``lathe_volpath``, ``max_depth`` 16) with
    or without ``caustics``."""
    return mi.load_dict({"type": kind, "max_depth": 16, "caustics": caustics,
                         "caustic_paths": caustic_paths, "caustic_camera_chains": camera_chains})


def chain_solve_rate(scene: mi.Scene, particles: int = 100_000, seed: int = 1) -> tuple[int, int, dict]:
    """Eqs. 37-40's solver on ``scene``: of ``particles`` particles traced
    from its lights, those that land where the camera's straight line is
    blocked all try the chain to the camera (``caustic_camera_chains`` 1);
    returns (how many tried, how many were solved, {vertices of a solved
    chain: how many})."""
    from ..plugin.camera_chain import solve_camera_chain

    integrator = path_integrator(True, camera_chains=1.0, kind=integrator_type(scene))
    sensor = scene.sensors()[0]
    tracer, why = integrator.caustic_setup(scene, sensor)
    if tracer is None:
        raise RuntimeError(f"no caustic paths to trace: {why}")
    geometry = integrator.geometry(scene)
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(seed, particles)
    behind = tracer._trace(scene, geometry, sensor, sampler, particles, mi.Float(1.0))[3]
    lanes = dr.compress(behind[0])
    _, si_d, _, _, chain_d = (dr.gather(type(value), value, lanes) for value in behind)
    limit = tracer.camera_chain_limit(chain_d)
    solution = solve_camera_chain(geometry, tracer.camera._origin, si_d.p, si_d.n, si_d.shape, limit,
                                  limit >= 1, media=tracer.media)
    found = np.array(solution.found, dtype=bool)
    vertices = np.array(solution.vertices)[found]
    return len(found), int(found.sum()), {int(k): int((vertices == k).sum()) for k in np.unique(vertices)}


def luminance(image: np.ndarray) -> np.ndarray:
    """(H, W): the mean of the RGB channels."""
    return np.asarray(image, dtype=np.float64)[..., :3].mean(axis=-1)


#: The regions, in the order they are printed.
REGION_NAMES = ("caustic", "glass", "glass_caustic", "glass_other", "image")


def regions(scene: mi.Scene, reference: np.ndarray, share: float = 0.1) -> dict[str, np.ndarray]:
    """The regions (see the module) as (H, W) bool masks."""
    return split_regions(glass_mask(scene), luminance(caustic_image(scene, 64)), luminance(reference), share)


def split_regions(glass: np.ndarray, caustic: np.ndarray, reference: np.ndarray,
                  share: float = 0.1) -> dict[str, np.ndarray]:
    """The regions of :data:`REGION_NAMES` as (H, W) bool masks, from the
    glass pixels ``glass`` (bool), the light-traced caustic's luminance
    ``caustic`` and the reference's ``reference``: the caustic shows where
    it carries at least ``share`` of the reference."""
    shows = (caustic >= share * np.maximum(reference, 1e-12)) & (reference > 0.0)
    return {"caustic": ~glass & shows, "glass": glass, "glass_caustic": glass & shows,
            "glass_other": glass & ~shows, "image": np.ones_like(glass)}


def rel_mae(image: np.ndarray, reference: np.ndarray, mask: np.ndarray) -> float:
    """Relative mean absolute error of the luminance on ``mask``."""
    a, b = luminance(image)[mask], luminance(reference)[mask]
    return float(np.abs(a - b).sum() / max(b.sum(), 1e-30))


def timed_render(scene: mi.Scene, integrator: mi.Integrator, spp: int, seed: int) -> tuple[np.ndarray, float]:
    """(image, seconds) of one render, evaluated."""
    start = time.perf_counter()
    image = mi.render(scene, integrator=integrator, spp=spp, seed=seed)
    dr.eval(image)
    image = np.array(image)
    return image, time.perf_counter() - start


def reference_image(scene: mi.Scene, name: str, resolution: int, spp: int, cache: str) -> np.ndarray:
    """The plain integrator at ``spp`` (cached in ``cache``), rendered in
    passes of 256 spp."""
    path = os.path.join(cache, f"caustics_ref_{name}_{resolution}_{spp}.npy")
    if os.path.exists(path):
        return np.load(path)
    plain = path_integrator(False, kind=integrator_type(scene))
    passes = max(1, spp // 256)
    total = None
    for index in range(passes):
        image = np.array(mi.render(scene, integrator=plain, spp=spp // passes, seed=100000 + index),
                         dtype=np.float64)
        total = image if total is None else total + image
    reference = total / passes
    np.save(path, reference)
    return reference


def measure(scene: mi.Scene, reference: np.ndarray, masks: dict, spp_list: list[int], repeats: int,
            caustic_paths: float, camera_chains: float) -> dict:
    """{(method, spp): {"time": median s, region: mean error, "rounds":
    [{"time": s, region: error} of each round]}} over ``repeats``
    interleaved rounds (after one warm-up render each)."""
    kind = integrator_type(scene)
    integrators = {"plain": path_integrator(False, kind=kind),
                   "caustics": path_integrator(True, caustic_paths, camera_chains, kind)}
    for integrator in integrators.values():
        timed_render(scene, integrator, spp_list[0], 0)
    runs: dict = {}
    for round_index in range(repeats):
        for spp in spp_list:
            for method, integrator in integrators.items():
                image, seconds = timed_render(scene, integrator, spp, 1 + round_index)
                entry = runs.setdefault((method, spp), [])
                entry.append({"time": seconds, **{region: rel_mae(image, reference, mask)
                                                  for region, mask in masks.items()}})
    return {key: {"time": statistics.median(run["time"] for run in rounds),
                  **{k: float(np.mean([run[k] for run in rounds])) for k in rounds[0] if k != "time"},
                  "rounds": rounds}
            for key, rounds in runs.items()}


def time_to_error(results: dict, method: str, region: str, target: float) -> float:
    """Seconds ``method`` needs to reach ``target`` error on ``region``,
    from its run nearest to it, with error ~ 1/sqrt(time)."""
    runs = [(v[region], v["time"]) for (m, _), v in results.items() if m == method]
    error, seconds = min(runs, key=lambda run: abs(np.log(run[0] / target)))
    return seconds * (error / target) ** 2


def time_ratio(results: dict, region: str, target_spp: int) -> tuple[float, float, float]:
    """The time the caustic renders need to reach plain's error at
    ``target_spp`` on ``region``, over plain's time: (from the medians and
    means over the rounds, the lowest and the highest of the rounds, each
    round's from its own runs alone)."""
    def ratio(runs: dict) -> float:
        plain = runs[("plain", target_spp)]
        return time_to_error(runs, "caustics", region, plain[region]) / plain["time"]
    count = len(results[("plain", target_spp)]["rounds"])
    rounds = [ratio({key: value["rounds"][index] for key, value in results.items()})
              for index in range(count)]
    return ratio(results), min(rounds), max(rounds)


def noise_floor(results: dict, region: str, reference_spp: int, spp: int) -> float:
    """The rel MAE two independent unbiased renders would show on
    ``region``: the reference's own error (plain at ``reference_spp``) and
    the caustic render's at ``spp``, each scaled from its measured run with
    the most samples as 1/sqrt(spp), added in quadrature."""
    def scaled(method: str, target: int) -> float:
        spp_run = max(s for m, s in results if m == method)
        return results[(method, spp_run)][region] * (spp_run / target) ** 0.5
    return float(np.hypot(scaled("plain", reference_spp), scaled("caustics", spp)))


def bench_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="bench_caustics.py",
        description="Caustics of lathe_path (and of lathe_volpath in the scenes with media): plain path "
                    "tracing against path tracing with light-traced caustic paths, error on the caustic "
                    "region, the glass pixels and the whole image against a high-spp plain reference, "
                    "and the time to reach plain's 256 spp error.")
    parser.add_argument("--scenes", nargs="+", default=["bottle", "wine_glass"], choices=sorted(SCENES),
                        help="scenes to measure (default: bottle wine_glass)")
    parser.add_argument("--resolution", type=square_side, default=256, metavar="NxN",
                        help="image size, NxN or N (default: 256x256)")
    parser.add_argument("--reference-spp", type=int, default=4096,
                        help="spp of the plain reference (default: 4096)")
    parser.add_argument("--spp", type=int, nargs="+", default=[4, 16, 64, 256],
                        help="spp of the timed renders (default: 4 16 64 256)")
    parser.add_argument("--target-spp", type=int, default=256,
                        help="plain lathe_path's spp whose caustic-region error is the target (default: 256)")
    parser.add_argument("--repeats", type=int, default=3,
                        help="interleaved renders per case, their median timed (default: 3)")
    parser.add_argument("--caustic-paths", type=float, default=CAUSTIC_PATHS,
                        help=f"lathe_path's caustic_paths (default: {CAUSTIC_PATHS})")
    parser.add_argument("--caustic-camera-chains", type=float, default=CAUSTIC_CAMERA_CHAINS,
                        help=f"lathe_path's caustic_camera_chains (default: {CAUSTIC_CAMERA_CHAINS})")
    parser.add_argument("--unbiased", type=int, default=0, metavar="SPP",
                        help="also render with caustics at SPP and compare its means with the reference")
    parser.add_argument("--variant", default="llvm_ad_rgb", help="Mitsuba variant (default: llvm_ad_rgb)")
    cache = os.path.join(tempfile.gettempdir(), "lathe_caustics_bench")
    parser.add_argument("--cache", default=cache, help=f"folder of the cached references (default: {cache})")
    parser.add_argument("--root", default=os.getcwd(), help="the repository (for scenes/)")
    parser.add_argument("--save", default=None, metavar="FOLDER",
                        help="write the 16 spp images (plain, caustics) and the reference as EXR here")
    parser.add_argument("--figure", default=None, metavar="PNG",
                        help="write the first scene's 16 spp frames, plain and with caustics, side by side")
    return parser


def run_bench(argv: list[str] | None = None) -> int:
    args = bench_parser().parse_args(argv)
    mi.set_variant(args.variant)
    import lathe_shape  # noqa: F401  (registers the plugins)

    os.makedirs(args.cache, exist_ok=True)
    print(f"variant {args.variant}, {args.resolution}x{args.resolution}, reference: the plain integrator at "
          f"{args.reference_spp} spp; errors: relative MAE of the luminance; times: medians of "
          f"{args.repeats} interleaved runs")
    for name in args.scenes:
        scene = load(name, args.root, args.resolution)
        reference = reference_image(scene, name, args.resolution, args.reference_spp, args.cache)
        masks = regions(scene, reference)
        sizes = {region: int(mask.sum()) for region, mask in masks.items()}
        # (a region without pixels, such as glass that shows no caustic, has no error)
        masks = {region: mask for region, mask in masks.items() if sizes[region] > 0}
        names = [region for region in REGION_NAMES if region in masks]
        print(f"\n== {name} ({integrator_type(scene)}): caustic region {sizes['caustic']} px, "
              f"glass {sizes['glass']} px")
        spp_list = sorted(set(args.spp) | {args.target_spp})
        results = measure(scene, reference, masks, spp_list, args.repeats, args.caustic_paths,
                          args.caustic_camera_chains)
        print(f"glass pixels showing a caustic (glass_caustic): {sizes['glass_caustic']} px, the others "
              f"(glass_other): {sizes['glass_other']} px")
        print(f"{'method':>9} {'spp':>5} {'time s':>8} " + " ".join(f"{region:>13}" for region in names))
        for (method, spp), v in sorted(results.items(), key=lambda kv: (kv[0][1], kv[0][0])):
            errors = " ".join(f"{v[region]:>13.4f}" for region in names)
            print(f"{method:>9} {spp:>5} {v['time']:>8.3f} {errors}")
        plain_target = results[("plain", args.target_spp)]
        for region in names:
            ratio, lowest, highest = time_ratio(results, region, args.target_spp)
            print(f"{region:>13}: time to plain {args.target_spp} spp's error {plain_target[region]:.4f}: "
                  f"{ratio:.3f} of plain's {plain_target['time']:.2f} s (rounds: {lowest:.3f}-{highest:.3f})")
        for spp in spp_list:
            print(f"cost per sample at {spp} spp: caustics/plain = "
                  f"{results[('caustics', spp)]['time'] / results[('plain', spp)]['time']:.2f}")
        tried, solved, by_vertices = chain_solve_rate(scene)
        counts = ", ".join(f"{k}: {v}" for k, v in by_vertices.items()) or "none"
        print(f"camera chains (eqs. 37-40): of 100000 particles, {tried} landed where the camera's "
              f"straight line is blocked; {solved} ({100 * solved / max(tried, 1):.1f}%) solved "
              f"(by chain vertices: {counts})")
        if args.save:
            from ..tools.images import write_exr

            os.makedirs(args.save, exist_ok=True)
            write_exr(os.path.join(args.save, f"{name}_reference.exr"), reference.astype(np.float32))
            for method in ("plain", "caustics"):
                integrator = path_integrator(method == "caustics", args.caustic_paths,
                                             args.caustic_camera_chains, integrator_type(scene))
                image, _ = timed_render(scene, integrator, 16, 1)
                write_exr(os.path.join(args.save, f"{name}_{method}_16spp.exr"), image)
        if args.figure and name == args.scenes[0]:
            from ..tools.images import write_png

            frames = []
            for method in ("plain", "caustics"):
                integrator = path_integrator(method == "caustics", args.caustic_paths,
                                             args.caustic_camera_chains, integrator_type(scene))
                image, _ = timed_render(scene, integrator, 16, 1)
                errors = ", ".join(f"{region} {rel_mae(image, reference, masks[region]):.3f}"
                                   for region in names)
                print(f"figure, 16 spp, {method}: {errors}")
                frames.append(image[..., :3])
            write_png(args.figure, np.concatenate(frames, axis=1))
        if args.unbiased:
            integrator = path_integrator(True, args.caustic_paths, args.caustic_camera_chains,
                                         integrator_type(scene))
            image = np.zeros_like(reference)
            passes = max(1, args.unbiased // 256)
            for index in range(passes):
                image += np.array(mi.render(scene, integrator=integrator, spp=args.unbiased // passes,
                                            seed=200000 + index)) / passes
            for region in names:
                mask = masks[region]
                mean, ref_mean = luminance(image)[mask].mean(), luminance(reference)[mask].mean()
                floor = noise_floor(results, region, args.reference_spp, args.unbiased)
                error = rel_mae(image, reference, mask)
                print(f"unbiased, {args.unbiased} spp, {region}: mean {mean:.5f} vs reference {ref_mean:.5f} "
                      f"({100 * (mean / ref_mean - 1):+.2f}%), rel MAE {error:.4f}, noise floor {floor:.4f}")
    return 0
