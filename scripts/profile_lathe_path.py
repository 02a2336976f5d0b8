"""Where the time of an exact render goes: differential timings of
`lathe_path` and stock `path`, and ray-query throughput on the same rays.

Renders (medians of --repeat interleaved renders):
  A  `path` on the scene without its lathes
  B  `lathe_path` on the scene without its lathes   (B - A: the Python integrator)
  C  `path` on the scene with the reference mesh    (C - A: the mesh)
  D  `lathe_path` on the scene                      (D - B: the exact lathes)
Ray queries (Mrays/s, camera rays of the scene's sensor, after a warm-up):
  the whole scene with the mesh (Embree/Mitsuba), the rest scene that
  lathe_path traces, one lathe's exact kernel, and lathe_path's merged query.

    python scripts/profile_lathe_path.py [SCENE.xml] [--resolution 256x256] [--spp 16]
                                         [--max-depth 8] [--repeat 5] [--variant llvm_ad_rgb]
"""

from __future__ import annotations

import time
from pathlib import Path

import drjit as dr
import mitsuba as mi

from lathe_shape.validation.bench import bench_arguments, bench_scene, interleaved_render_times, median_spread

ROOT = Path(__file__).resolve().parents[1]


def without_lathes(scene: mi.Scene) -> mi.Scene:
    """The scene's sensor, integrator, environment and non-lathe shapes (with
    their area lights), without its lathes."""
    from lathe_shape.plugin.shape import scene_lathes

    lathes = {lathe.ptr for lathe in scene_lathes(scene)}
    parts: dict[str, object] = {"type": "scene", "sensor": scene.sensors()[0]}
    parts.update({f"emitter_{k}": e for k, e in enumerate(scene.emitters()) if e.get_shape() is None})
    parts.update({f"shape_{k}": s for k, s in enumerate(scene.shapes()) if s.ptr not in lathes})
    return mi.load_dict(parts)


def camera_rays(scene: mi.Scene, spp: int) -> mi.Ray3f:
    """``spp`` jittered camera rays per pixel of the scene's first sensor."""
    sensor = scene.sensors()[0]
    width, height = sensor.film().size()
    index = dr.arange(mi.UInt32, width * height * spp)
    pixel = index // spp
    sampler = mi.load_dict({"type": "independent"})
    sampler.seed(0, width * height * spp)
    position = (mi.Point2f(mi.Float(pixel % width), mi.Float(pixel // width)) + sampler.next_2d())
    ray, _ = sensor.sample_ray(0.0, 0.5, position / mi.ScalarVector2f(width, height), mi.Point2f(0.5))
    dr.eval(ray)
    return ray


def throughput(query, ray: mi.Ray3f, repeat: int) -> float:
    """Median Mrays/s of ``query(ray)`` (evaluated), after one warm-up. Each
    run gets a new (opaque) ``maxt``: Dr.Jit would otherwise hand back the
    result of the identical query it already evaluated."""
    def fresh(k: int) -> mi.Ray3f:
        copy = mi.Ray3f(ray)
        copy.maxt = dr.opaque(mi.Float, 1e30 * (1 + k))
        return copy

    dr.eval(query(fresh(0)))
    dr.sync_thread()
    times = []
    for k in range(repeat):
        r = fresh(k + 1)
        start = time.perf_counter()
        dr.eval(query(r))
        dr.sync_thread()  # kernels run asynchronously: wait for them
        times.append(time.perf_counter() - start)
    return dr.width(ray.o) / median_spread(times)[0] * 1e-6


def main() -> None:
    args = bench_arguments(__doc__.splitlines()[0], repeat=5, extra=lambda parser: parser.add_argument(
        "scene", nargs="?", default=str(ROOT / "scenes" / "brandy_bottle.xml"), help="scene file"))
    from lathe_shape.plugin.lathe_path import LathePathIntegrator
    from lathe_shape.plugin.shape import scene_lathes

    scene = bench_scene(args, args.scene)
    bare = without_lathes(scene)
    path = mi.load_dict({"type": "path", "max_depth": args.max_depth})
    exact = mi.load_dict({"type": "lathe_path", "max_depth": args.max_depth})
    cases = {"A path, no lathes": (bare, path), "B lathe_path, no lathes": (bare, exact),
             "C path, mesh": (scene, path), "D lathe_path, exact": (scene, exact)}
    times = {name: median_spread(values)[0]
             for name, values in interleaved_render_times(cases, args.spp, args.repeat, args.seed).items()}
    width, height = args.size
    print(f"{Path(args.scene).name}, variant {args.variant}, {width}x{height}, {args.spp} spp, "
          f"max_depth {args.max_depth}, medians of {args.repeat} interleaved renders")
    for name, seconds in times.items():
        print(f"  {name:<26}{seconds:8.3f} s")
    a, b, c, d = times.values()
    print(f"  the Python integrator (B - A) {b - a:+.3f} s, the mesh in path (C - A) {c - a:+.3f} s, "
          f"the exact lathes in lathe_path (D - B) {d - b:+.3f} s; D / C = {d / c:.2f}x")

    ray = camera_rays(scene, args.spp)
    assert isinstance(exact, LathePathIntegrator)
    geometry = exact.geometry(scene)
    lathe = scene_lathes(scene)[0]
    active = mi.Bool(True)
    queries = {
        "scene with the mesh (Mitsuba)": lambda r: scene.ray_intersect(r).t,
        "rest scene (Mitsuba)": lambda r: geometry.rest.ray_intersect(r).t,
        "one lathe, exact kernel": lambda r: lathe.ray_intersect_exact(r).t,
        "lathe_path's merged query": lambda r: geometry.ray_intersect(r, active).t,
    }
    print(f"ray queries, {dr.width(ray.o):,} camera rays (Mrays/s, median of {args.repeat}):")
    for name, query in queries.items():
        print(f"  {name:<32}{throughput(query, ray, args.repeat):8.1f}")


if __name__ == "__main__":
    main()
