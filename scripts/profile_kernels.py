"""Where a render's time goes, kernel by kernel (Dr.Jit's kernel history):
plain ``lathe_path`` against ``lathe_path`` with ``caustics`` on a scene of
``bench_caustics.py``, or (``--gradient``) the primal render and one
backward pass of ``lathe_prb`` on the clear wine glass of
``bench_gradients.py --kind glass``. After a warm-up of each (JIT
compilation), prints for each case (--repeat times, interleaved) its wall time, the number of kernel
launches and their summed execution time, and its most expensive kernels
(wavefront size, IR operations, milliseconds).

    python scripts/profile_kernels.py [--scene bottle] [--resolution 256x256] [--spp 16] [--top 8]
    python scripts/profile_kernels.py --gradient [--resolution 512x512] [--spp 32] [--max-depth 8]
    python scripts/profile_kernels.py --variant cuda_ad_rgb [--repeat 3] ...

The rest of a case's wall time, beyond its kernels' execution and
compilation, is the host's: Python tracing the integrator's code and
Dr.Jit launching the kernels.
"""

from __future__ import annotations

import contextlib
import time
from pathlib import Path

import drjit as dr
import mitsuba as mi

from lathe_shape.validation.bench import bench_arguments

ROOT = Path(__file__).resolve().parent.parent


def profiled(run, top: int) -> dict:
    """Runs ``run()`` once with Dr.Jit's kernel history on; returns its
    wall time, launches, summed kernel time and the ``top`` kernels."""
    dr.sync_thread()
    dr.set_flag(dr.JitFlag.KernelHistory, True)
    dr.kernel_history()  # clears the history
    start = time.perf_counter()
    run()
    dr.sync_thread()
    seconds = time.perf_counter() - start
    history = dr.kernel_history()
    dr.set_flag(dr.JitFlag.KernelHistory, False)
    kernels = [k for k in history if k["type"] == dr.KernelType.JIT]
    others = len(history) - len(kernels)  # reductions, copies, sorts
    kernels.sort(key=lambda k: -k["execution_time"])
    return {"seconds": seconds, "launches": len(kernels), "others": others,
            "kernel_ms": sum(k["execution_time"] for k in kernels),
            "codegen_ms": sum(k["codegen_time"] + k["backend_time"] for k in kernels),
            "cached": sum(1 for k in kernels if k["cache_hit"]),
            "top": [(int(k["size"]), int(k["operation_count"]), k["execution_time"]) for k in kernels[:top]]}


def report(name: str, profile: dict) -> None:
    print(f"{name}: {profile['seconds'] * 1000:.1f} ms wall, {profile['launches']} kernels "
          f"(and {profile['others']} other operations), "
          f"{profile['kernel_ms']:.1f} ms in kernels, {profile['codegen_ms']:.1f} ms assembling and "
          f"compiling them ({profile['cached']} found in the kernel cache)")
    for size, operations, ms in profile["top"]:
        print(f"    {ms:9.2f} ms  size {size:>9d}  {operations:>6d} ops")


def main(argv: list[str] | None = None) -> int:
    def own_options(parser):
        parser.add_argument("--scene", default="bottle",
                            help="a scene of bench_caustics.py, rendered at that script's max_depth "
                                 "of 16 (default: bottle)")
        parser.add_argument("--gradient", action="store_true",
                            help="lathe_prb's backward pass on the clear wine glass (at --max-depth)")
        parser.add_argument("--top", type=int, default=8, help="kernels listed per case (default: 8)")

    args = bench_arguments(__doc__.splitlines()[0], argv, repeat=1, extra=own_options)
    width, height = args.size
    if height != width:
        raise SystemExit("profile_kernels.py: --resolution must be square (WxW)")
    with contextlib.ExitStack() as stack:
        if args.gradient:
            from lathe_shape.tools.diff_scenes import glass_scene
            from lathe_shape.tools.gradients import gradient_passes

            scene = glass_scene(str(ROOT / "scenes" / "wine_glass.csv"), resolution=width,
                                max_depth=args.max_depth)
            # glass_scene's lathe_prb has no Russian roulette: nor has the primal
            primal = mi.load_dict({"type": "lathe_path", "max_depth": args.max_depth,
                                   "rr_depth": args.max_depth})
            passes = stack.enter_context(gradient_passes(scene, primal, args.spp))
            cases = {"primal (lathe_path)": passes["primal"], "backward (lathe_prb)": passes["backward"]}
        else:
            from lathe_shape.validation.caustics_bench import SCENES, load, path_integrator

            if args.scene not in SCENES:
                raise SystemExit(f"profile_kernels.py: unknown --scene '{args.scene}' "
                                 f"(expected one of: {', '.join(SCENES)})")
            scene = load(args.scene, str(ROOT), width)

            def renderer(caustics: bool):
                integrator = path_integrator(caustics)
                return lambda seed: mi.render(scene, spp=args.spp, seed=seed, integrator=integrator).numpy()

            cases = {f"{name} {args.scene}": renderer(caustics)
                     for name, caustics in (("plain", False), ("caustics", True))}
        for run in cases.values():
            run(args.seed)  # the warm-up: JIT compilation
        for k in range(1, args.repeat + 1):
            for name, run in cases.items():
                report(name, profiled(lambda: run(args.seed + k), args.top))  # noqa: B023 (called at once)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
