"""The commands' Dask options (``--scheduler``, ``--workers``, ``--collect``)
and ``lathe-turntable``'s distributed run: every pending frame is a task
(:mod:`lathe_shape.distributed`, imported only when a cluster is asked for;
``distributed`` is the optional extra ``lathe_shape[cluster]``).

``--scheduler tcp://host:8786`` sends the frames to a running Dask cluster;
``--workers N`` starts a ``LocalCluster`` of N worker processes here (each
with ``--threads`` Dr.Jit threads, by default the cores shared out). The
workers write the frames into the output folder, which must then be on a
filesystem they share, through a hidden staging folder (a frame's PNG and
EXR move into place when whole); with ``--collect`` they send the images
back and this process writes them. The run takes the output folder's lock
(:mod:`.folder_lock`) as a single-process run does, resumes the same way
(finished frames are skipped) and writes the same pixels (with one Dr.Jit
thread, bit for bit, see :mod:`lathe_shape.distributed`). On Ctrl-C the
futures are cancelled, the local workers end, and the command exits 130.
"""

from __future__ import annotations

import argparse
import copy
import functools
import os
import time
from typing import TYPE_CHECKING

from . import interrupts
from .common import CliError, ProgressBar, check_at_least, is_interrupt

if TYPE_CHECKING:
    from .turntable import Job

__all__ = ["add_cluster_options", "check_cluster_options", "client_args", "render_job_on_cluster",
           "uses_cluster", "worker_threads"]


def add_cluster_options(parser: argparse.ArgumentParser, collect: bool = False) -> None:
    """``--scheduler``, ``--workers`` and (turntables) ``--collect``."""
    group = parser.add_argument_group(
        "Dask cluster (pip install 'lathe_shape[cluster]')")
    paths = ("the scene (and, unless --collect, the output folder)" if collect else
             "the scene (this process writes the outputs)")
    group.add_argument(
        "--scheduler", metavar="ADDRESS",
        help="render on the Dask cluster whose scheduler is at ADDRESS (e.g. tcp://host:8786); its "
        f"workers need lathe_shape installed and {paths} under the same paths")
    group.add_argument(
        "--workers", type=int, metavar="N",
        help="render on a local Dask cluster of N worker processes started for the run (each with "
        "--threads Dr.Jit threads; default: the cores shared out among them)")
    if collect:
        group.add_argument(
            "--collect", action="store_true",
            help="the workers send the frames back and this process writes them (when the output "
            "folder is not on a filesystem the workers share)")


def uses_cluster(args: argparse.Namespace) -> bool:
    """Whether the run is distributed (after :func:`check_cluster_options`)."""
    return bool(getattr(args, "scheduler", None)) or getattr(args, "workers", None) is not None


def check_cluster_options(args: argparse.Namespace) -> None:
    """Check the cluster options, and that ``distributed`` is installed when
    they ask for a cluster (:class:`CliError` naming the extra)."""
    if args.scheduler is not None and args.workers is not None:
        raise CliError("--scheduler and --workers exclude each other: --workers starts a local cluster, "
                       "--scheduler uses the workers of a running one")
    if args.scheduler is not None and not args.scheduler.strip():
        raise CliError("--scheduler expects an address, e.g. tcp://host:8786")
    check_at_least("--workers", args.workers, 1)
    if getattr(args, "collect", False) and not uses_cluster(args):
        raise CliError("--collect needs --scheduler or --workers")
    if uses_cluster(args):
        from ..distributed import ClusterError, require_distributed

        try:
            require_distributed("--scheduler" if args.scheduler else "--workers")
        except ClusterError as e:
            raise CliError(str(e)) from None


def worker_threads(args: argparse.Namespace) -> int | None:
    """Dr.Jit threads per worker: ``--threads``; for ``--workers N`` by
    default the cores this process may use shared out among the N workers;
    None (the workers' own default) for a remote cluster."""
    if args.threads is not None:
        return args.threads
    if args.workers is None:
        return None
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    return max(1, cores // args.workers)


def client_args(args: argparse.Namespace) -> argparse.Namespace:
    """The options this process loads the scene with (to check it and plan
    the job): a CUDA ``--variant`` this machine cannot run (a login node
    sending frames to GPU workers) is checked with its LLVM counterpart."""
    if not (uses_cluster(args) and args.variant.startswith("cuda_")):
        return args
    import drjit as dr
    import mitsuba as mi

    if dr.has_backend(dr.JitBackend.CUDA):
        return args
    cpu = "llvm_" + args.variant[len("cuda_"):]
    if cpu not in mi.variants():
        return args
    local = copy.copy(args)
    local.variant = cpu
    return local


def _where(args: argparse.Namespace, client: object, threads: int | None) -> str:
    from ..distributed import worker_count

    each = "" if threads is None else f", {threads} Dr.Jit thread(s) each"
    if args.scheduler:
        return f"  on the Dask cluster at {args.scheduler} ({worker_count(client)} worker(s) now{each})"
    return f"  on a local Dask cluster of {args.workers} worker process(es){each}"


def render_job_on_cluster(job: Job, prog: str) -> int:
    """Render the job's pending frames as Dask tasks with a progress bar over
    the frames; returns 0, or 130 (with a one-line message) on Ctrl-C. A
    frame that fails twice stops the job (:class:`CliError` with its error)."""
    from ..distributed import (
        ClusterError,
        RenderSpec,
        cancel,
        cluster_client,
        completed,
        local_worker_pids,
        stop_local_workers,
        submit_frames,
    )
    from ..tools.frames import plan_frames
    from ..tools.writer import FrameWriter
    from .turntable import finish_frame, pending_frames, print_turn_summary

    args = job.args
    frames = plan_frames(args.count, job.indices, job.out_dir, args.seed, same_seed=args.seeds == "same")
    todo = pending_frames(job, frames)
    progress = ProgressBar(len(frames), done=len(frames) - len(todo))
    threads = worker_threads(args)
    spec = RenderSpec(
        scene=os.path.abspath(args.scene), variant=args.variant, defines=tuple(args.defines or ()),
        resolution=args.resolution, spp=job.spp, threads=threads, mode=job.turntable.mode,
        object_id=args.object, denoiser="" if job.denoiser is None else job.denoiser.backend,
        multijitter=args.multijitter)
    futures: list = []
    state: dict[str, object] = {}

    def interrupted() -> str:
        return (f"{prog}: interrupted after {progress.rendered} rendered frame(s); "
                "run the same command again to resume")

    def on_ctrl_c() -> None:  # (the watcher's clean-up, in a command process, before children end)
        if "client" not in state:
            return
        if args.scheduler:
            cancel(state["client"], futures, timeout=1.0)
        else:
            stop_local_workers(state["client"], state["pids"])

    start = time.perf_counter()
    try:
        with interrupts.message(lambda: ("\n" if progress.interactive else "") + interrupted()), \
                interrupts.on_interrupt(on_ctrl_c, first=True):
            if not todo:
                progress.close()
                print(f"  nothing to render; output folder {job.out_dir}", flush=True)
                return 0
            with cluster_client(args.scheduler, args.workers) as client, \
                    interrupts.Staging(job.out_dir) as staging, \
                    FrameWriter(workers=2) as writer:
                state["client"], state["pids"] = client, local_worker_pids(client)
                print(_where(args, client, threads), flush=True)
                progress.show()
                planned = ((frames.frame(index), job.metadata(frames.frame(index))) for index in todo)
                target = None if args.collect else staging.path
                submitted, names = submit_frames(client, spec, planned, target)
                futures.extend(submitted)
                for result in completed(client, futures, names):
                    if args.collect:
                        frame = frames.frame(result.index)
                        writer.submit(functools.partial(finish_frame, job, frame, None, result.seconds,
                                                        (result.rgb, result.noisy), staging))
                    progress.advance(result.seconds)
    except ClusterError as e:
        progress.close()
        raise CliError(str(e)) from None
    except BaseException as e:
        progress.close()
        if not is_interrupt(e):
            raise
        interrupts.print_message(interrupted())
        return 130
    progress.close()
    print_turn_summary(progress.rendered, len(frames), job.out_dir, start)
    return 0
