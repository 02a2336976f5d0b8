"""Turntable frames on a local Dask cluster: frames per second for 1, 2 and 4
worker processes, and the scheduling overhead per frame relative to the
frame time.

Every configuration renders the same turn (``--frames`` frames of
``--resolution`` at ``--spp``, written as EXR + PNG) with the task the
workers run (:func:`lathe_shape.distributed.render_turntable_frame`):

* ``in-process`` -- that task called in a loop in this process, with all
  the cores as Dr.Jit threads: the frame time without Dask;
* ``1 worker x C threads`` -- the same work as one task per frame on a
  LocalCluster of one worker process;
* ``N workers x C/N threads`` -- the cores shared among N processes (on a
  2-core machine: 2 workers of 1 thread against 1 worker of 2 threads; 4
  workers oversubscribe the cores).

The clusters start, load the scene and compile the kernels before any
timing (one warm-up turn each); the timed turns of all configurations are
interleaved, ``--repeats`` rounds, and the medians reported.

The scheduling overhead per frame is the time the workers spend outside
the frames' tasks (submit, scheduler, transfer of the task and its result,
the client's bookkeeping): ``(wall x workers - sum of the task times) /
frames``, relative to the frame time (the median task time: render and
writes); the target is below 5% for 1 worker. The wall time per turn
against ``in-process`` adds what else differs in a worker process (and on
a loaded machine, the contention of the other processes).

    python scripts/bench_cluster.py                  # 256x256, 16 spp, 16 frames, 3 rounds
    python scripts/bench_cluster.py --frames 32 --repeats 5 --workers 1 2
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--scene", default=str(ROOT / "scenes" / "wine_glass.xml"),
                        help="scene (default: the repository's scenes/wine_glass.xml)")
    parser.add_argument("--resolution", default="256", help="frame size, WxH or N (default: 256)")
    parser.add_argument("--spp", type=int, default=16, help="samples per pixel (default: 16)")
    parser.add_argument("--frames", type=int, default=16, help="frames per timed turn (default: 16)")
    parser.add_argument("--repeats", type=int, default=3, help="interleaved rounds (default: 3)")
    parser.add_argument("--workers", type=int, nargs="+", default=[1, 2, 4],
                        help="local cluster sizes to measure (default: 1 2 4)")
    parser.add_argument("--variant", default="llvm_ad_rgb", help="Mitsuba variant (default: llvm_ad_rgb)")
    parser.add_argument("-D", dest="defines", action="append", default=[], metavar="KEY=VALUE")
    return parser.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    import logging
    from contextlib import ExitStack

    import drjit as dr

    from lathe_shape.distributed import (
        RenderSpec,
        cluster_client,
        completed,
        preload,
        render_turntable_frame,
        submit_frames,
    )
    from lathe_shape.tools.frames import plan_frames

    logging.getLogger("distributed").setLevel(logging.ERROR)
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)

    def spec(threads: int) -> RenderSpec:
        return RenderSpec(os.path.abspath(args.scene), args.variant, tuple(args.defines), args.resolution,
                          args.spp, threads, mode="orbit")

    scratch = Path(tempfile.mkdtemp(prefix="bench_cluster_"))
    runs = iter(range(10**9))

    def turn() -> tuple[list, str, str]:
        """(frames with metadata, output folder, staging folder) of a fresh turn."""
        out = scratch / f"turn{next(runs)}"
        staging = out / ".staging"
        staging.mkdir(parents=True)
        frames = plan_frames(args.frames, range(args.frames), out, seed=0, same_seed=True)
        return [(f, {"frame": f.index, "angle_deg": f.angle_deg}) for f in frames], str(out), str(staging)

    # In this process: the same task, all cores.
    local_spec = spec(cores)
    preload(local_spec)
    dr.set_thread_count(cores)

    def run_local() -> tuple[float, list]:
        planned, out, staging = turn()
        start = time.perf_counter()
        results = [render_turntable_frame(local_spec, f, meta, staging) for f, meta in planned]
        wall = time.perf_counter() - start
        shutil.rmtree(out)
        return wall, results

    configs: dict[str, object] = {"in-process": run_local}
    processes: dict[str, int] = {"in-process": 1}
    clusters = ExitStack()
    for workers in args.workers:
        threads = max(1, cores // workers)
        worker_spec = spec(threads)
        started = time.perf_counter()
        client = clusters.enter_context(cluster_client(workers=workers))  # (what --workers starts)
        client.run(preload, worker_spec)

        def run_cluster(client=client, worker_spec=worker_spec) -> tuple[float, list]:
            planned, out, staging = turn()
            start = time.perf_counter()
            futures, names = submit_frames(client, worker_spec, planned, staging)
            results = list(completed(client, futures, names))
            wall = time.perf_counter() - start
            shutil.rmtree(out)
            return wall, results

        run_cluster()  # warm-up: every worker compiles its kernels
        print(f"  started {workers} worker(s) x {threads} thread(s), loaded and warmed up in "
              f"{time.perf_counter() - started:.1f} s", file=sys.stderr, flush=True)
        configs[f"{workers} worker(s) x {threads} thread(s)"] = run_cluster
        processes[f"{workers} worker(s) x {threads} thread(s)"] = workers
    run_local()  # warm-up

    walls: dict[str, list[float]] = {name: [] for name in configs}
    renders: dict[str, list[float]] = {name: [] for name in configs}
    tasks: dict[str, list[float]] = {name: [] for name in configs}
    gaps: dict[str, list[float]] = {name: [] for name in configs}  # per round: idle worker time / frame
    for round_ in range(args.repeats):
        for name, run in configs.items():
            wall, results = run()
            walls[name].append(wall)
            renders[name].extend(r.seconds for r in results)
            tasks[name].extend(r.task_seconds for r in results)
            gaps[name].append((wall * processes[name] - sum(r.task_seconds for r in results)) / len(results))
        print(f"  round {round_ + 1}/{args.repeats}: "
              + ", ".join(f"{n} {walls[n][-1]:.2f} s" for n in configs), file=sys.stderr, flush=True)
    clusters.close()
    shutil.rmtree(scratch, ignore_errors=True)

    n = args.frames
    print(f"bench_cluster: {os.path.basename(args.scene)} {args.resolution} px, {args.spp} spp, {n} frames "
          f"per turn (EXR + PNG written), {args.repeats} interleaved rounds, medians; {cores} cores, "
          f"variant {args.variant}")
    print(f"  {'configuration':<26} {'wall/turn':>10} {'frames/s':>9} {'render/frame':>13} "
          f"{'task/frame':>11} {'vs in-process':>14} {'overhead/frame':>21}")
    base = statistics.median(walls["in-process"])
    for name in configs:
        wall = statistics.median(walls[name])
        task = statistics.median(tasks[name])
        gap = statistics.median(gaps[name])
        overhead = "" if name == "in-process" else f"{gap * 1e3:+7.1f} ms {gap / task:+6.1%}"
        render = statistics.median(renders[name])
        print(f"  {name:<26} {wall:>8.3f} s {n / wall:>9.2f} {render * 1e3:>10.1f} ms "
              f"{task * 1e3:>8.1f} ms {base / wall:>13.2f}x {overhead:>21}")
    one = next((name for name in configs if name.startswith("1 worker")), None)
    if one is not None:
        gap, task = statistics.median(gaps[one]), statistics.median(tasks[one])
        verdict = "met" if gap / task < 0.05 else "NOT met"
        print(f"  scheduling overhead per frame, {one}: {gap * 1e3:.1f} ms on a frame time of "
              f"{task * 1e3:.1f} ms = {gap / task:.1%} (target < 5%: {verdict}); wall time per frame "
              f"against in-process: {(statistics.median(walls[one]) - base) / base:+.1%}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
