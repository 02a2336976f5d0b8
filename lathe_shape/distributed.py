"""Turntables, sequences and sweeps on a Dask cluster (the optional extra
``pip install 'lathe_shape[cluster]'``, which brings Dask's ``distributed``;
this module imports it only when a cluster is asked for).

Each render is one task. A worker process loads a scene once (a cache of
:data:`CACHE_SIZE` scenes per process, keyed by the :class:`RenderSpec`)
and renders the frames it is given, one at a time whatever its thread count
(the posed scene is the process's), with the Dr.Jit thread count of the
spec. A frame is rendered exactly as ``lathe-turntable`` renders it in one
process (same pose, sample count and seed), so on the same machine and
variant it gives the same pixels, bit for bit: with a reconstruction filter
wider than a pixel (Mitsuba's default gaussian) that takes one Dr.Jit thread
(``threads=1``), as it does for two runs of the single-process command.

Failures: a worker that dies mid-frame loses nothing (the scheduler gives
the frame to another worker); a render that raises is tried once more
(``retries=1``, perhaps elsewhere) and a second failure stops the job with
its error (:class:`ClusterError`), cancelling the frames not yet rendered.

The pieces:

* :func:`cluster_client` -- a ``Client`` of the scheduler at an address, or
  of a ``LocalCluster`` of N worker processes started here;
* :func:`render_turntable_frame` -- the task of one turntable frame (written
  by the worker into the output folder on a shared filesystem, or returned);
* :func:`render_variation` / :func:`render_many` -- a parameter sweep: one
  render per dict of ``-D`` values, or per profile file of the scene's first
  lathe;
* :func:`completed` -- the finished futures as they come, with the
  one-retry rule and Ctrl-C within a tenth of a second.

Example::

    from distributed import Client
    from lathe_shape.distributed import render_many

    client = Client("tcp://head-node:8786")
    renders = render_many("scenes/wine_glass.xml",
                          [{"mesh_segments": "64"}, {"mesh_segments": "512"}], client,
                          spp=64, resolution="256")
    for r in renders:
        print(r.variation, r.image.shape, r.seconds)
"""

from __future__ import annotations

import argparse
import itertools
import numbers
import os
import re
import shutil
import socket
import threading
import time
import uuid
from collections import OrderedDict
from collections.abc import Iterable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # (numpy and the Dask types: only where used)
    import numpy as np
    from distributed import Client, Future

    from .tools.frames import Frame

__all__ = [
    "CACHE_SIZE",
    "EXTRA",
    "INSTALL_HINT",
    "ClusterError",
    "FrameResult",
    "Render",
    "RenderSpec",
    "cluster_client",
    "completed",
    "render_many",
    "render_turntable_frame",
    "product",
    "halt",
    "render_variation",
    "require_distributed",
    "stop_local_workers",
    "sweep_specs",
    "variation_spec",
    "worker_count",
]

#: The optional dependency group that brings Dask's ``distributed``.
EXTRA = "cluster"
#: How to install it.
INSTALL_HINT = f"pip install 'lathe_shape[{EXTRA}]'"
#: Scenes a worker process keeps loaded (a turntable needs one; a sweep
#: loads one per variation).
CACHE_SIZE = 2
#: Seconds between two looks at the futures (and at Ctrl-C) while waiting.
POLL_SECONDS = 0.05
#: Tries of a render that raises: the first and one retry.
TRIES = 2
#: Dask settings of the workers of a local cluster (remote workers: set
#: ``DASK_DISTRIBUTED__WORKER__PROFILE__ENABLED=False`` where they start).
WORKER_CONFIG = {"distributed.worker.profile.enabled": False}
#: Environment variable of the tests' fault injection on the workers:
#: ``delay=SECONDS`` (before every render), ``fail=K`` (frame or variation K
#: raises a scene error every time), ``log=PATH`` (each failure appends a
#: line to PATH).
FAULTS_ENV = "LATHE_CLUSTER_FAULTS"


class ClusterError(RuntimeError):
    """A distributed job cannot run or stopped; the message says why."""


def require_distributed(what: str = "a Dask cluster") -> Any:
    """The ``distributed`` module, or :class:`ClusterError` naming the extra
    that installs it."""
    try:
        import distributed
    except ImportError:
        raise ClusterError(f"{what} needs Dask's 'distributed' package, which is not installed: "
                           f"{INSTALL_HINT}") from None
    return distributed


# -- What a worker renders ---------------------------------------------------------------


@dataclass(frozen=True)
class RenderSpec:
    """A scene as a worker loads and renders it (hashable: the key of the
    worker's cache). ``scene`` is an absolute path the workers can read;
    ``defines`` the ``-D KEY=VALUE`` items; ``profile`` replaces the profile
    file of the scene's first lathe; ``mode``/``object_id``/``denoiser``/
    ``multijitter`` are the turntable's (``denoiser``: the backend, "" for
    none); ``threads`` the Dr.Jit thread count (None: the worker's
    default)."""

    scene: str
    variant: str
    defines: tuple[str, ...] = ()
    resolution: str | None = None
    spp: int | None = None
    threads: int | None = None
    mode: str | None = None
    object_id: str | None = None
    denoiser: str = ""
    multijitter: bool = False
    profile: str | None = None


@dataclass
class FrameResult:
    """What a turntable frame's task returns: the frame, its render time and
    where it ran; the image (``rgb``, and ``noisy`` when denoised) only when
    the client writes it (``collect``)."""

    index: int
    seconds: float
    worker: str
    rgb: np.ndarray | None = None
    noisy: np.ndarray | None = None
    #: The whole task's time in the worker (render, denoise, writes).
    task_seconds: float = 0.0


@dataclass
class Render:
    """One render of a sweep: the variation (its ``-D`` values, or the
    profile file under the key ``profile``), the image (H, W, C) float32 with
    its channel names, and the render time in seconds."""

    index: int
    variation: dict[str, str]
    image: np.ndarray
    channels: list[str]
    seconds: float
    worker: str = ""
    defines: dict[str, str] = field(default_factory=dict)


@dataclass
class _Loaded:
    """A scene loaded in a worker: a Turntable (turntables) or the scene (sweeps)."""

    scene: Any
    turntable: Any = None
    denoiser: Any = None


_cache: OrderedDict[RenderSpec, _Loaded] = OrderedDict()
#: One render at a time per process: the posed scene (and Dr.Jit's thread
#: count) belong to the process, whatever the worker's thread count.
_render_lock = threading.Lock()


def _worker_name() -> str:
    return f"{socket.gethostname()}:{os.getpid()}"


def _profile_edit(profile: str):
    """The scene text edit that points the first lathe at the profile file ``profile``."""
    from .tools.scenes import SceneError

    def edit(text: str, path: str) -> str:
        lathe = re.search(r"<shape\s+type\s*=\s*[\"']lathe[\"'][^>]*>", text)
        if lathe is None:
            raise SceneError(f"{path}: the scene has no <shape type=\"lathe\"> whose profile to replace")
        end = text.find("</shape>", lathe.end())
        body = text[lathe.end(): end if end >= 0 else len(text)]
        name = re.search(r"(<string\s+name\s*=\s*[\"']filename[\"']\s+value\s*=\s*)([\"'])(.*?)\2", body)
        if name is None:
            raise SceneError(f"{path}: the first lathe takes no profile file (no <string name=\"filename\">)")
        start = lathe.end() + name.start(3)
        return text[:start] + os.path.abspath(profile) + text[lathe.end() + name.end(3):]

    return edit


def _load(spec: RenderSpec, turntable: bool) -> _Loaded:
    """The worker's loaded scene of ``spec`` (loaded at the first call)."""
    loaded = _cache.get(spec)
    if loaded is not None:
        _cache.move_to_end(spec)
        return loaded
    import drjit as dr

    from .cli.common import open_scene
    from .cli.turntable import scene_edit

    edits = [scene_edit(argparse.Namespace(denoise=bool(spec.denoiser), multijitter=spec.multijitter))]
    if spec.profile is not None:
        edits.append(_profile_edit(spec.profile))
    edits = [e for e in edits if e is not None]

    def edit(text: str, path: str) -> str:
        for one in edits:
            text = one(text, path)
        return text

    scene = open_scene(spec.scene, spec.variant, list(spec.defines), spec.resolution,
                       edit=edit if edits else None)
    if spec.threads is not None:
        dr.set_thread_count(spec.threads)
    loaded = _Loaded(scene)
    if turntable:
        from .tools.denoise import Denoiser
        from .tools.turntable import Turntable

        loaded.turntable = Turntable(scene, spec.mode, spec.object_id, scene_path=spec.scene,
                                     guides=bool(spec.denoiser))
        if spec.denoiser:
            to_sensor = loaded.turntable.sensor.world_transform().inverse()
            loaded.denoiser = Denoiser(spec.denoiser, to_sensor=to_sensor)
    while len(_cache) >= CACHE_SIZE:
        _cache.popitem(last=False)
    _cache[spec] = loaded
    return loaded


def _faults(position: int) -> None:
    """The tests' fault injection (:data:`FAULTS_ENV`)."""
    text = os.environ.get(FAULTS_ENV)
    if not text:
        return
    from .tools.scenes import SceneError

    faults = dict(item.partition("=")[::2] for item in text.split(","))
    if "delay" in faults:
        time.sleep(float(faults["delay"]))
    if "fail" in faults and int(faults["fail"]) == position:
        if "log" in faults:
            with open(faults["log"], "a", encoding="utf-8") as f:
                f.write(f"{position} {_worker_name()}\n")
        raise SceneError(f"injected failure of render {position}")


def preload(spec: RenderSpec, turntable: bool = True) -> str:
    """Load ``spec``'s scene in this worker now (e.g. from ``client.run``, so
    that no frame waits for it); returns the worker's name."""
    with _render_lock:
        _load(spec, turntable)
    return _worker_name()


def render_turntable_frame(spec: RenderSpec, frame: Frame, metadata: Mapping[str, object],
                           staging: str | None) -> FrameResult:
    """The task of one turntable frame: render ``frame`` of the turntable
    ``spec`` (denoised when ``spec.denoiser``); with ``staging`` (a folder
    inside the output folder, on a filesystem the workers share) write its
    EXR (with ``metadata`` and the render time) and PNG there and move them
    into place (the EXR last: a frame whose EXR is there is whole), else
    return the image for the client to write."""
    task_start = time.perf_counter()
    _faults(frame.index)
    with _render_lock:
        loaded = _load(spec, turntable=True)
        start = time.perf_counter()
        image = loaded.turntable.render(frame.angle_deg, spec.spp, frame.seed)
        seconds = time.perf_counter() - start
        rgb, noisy = image[..., :3], None
        if loaded.denoiser is not None:
            rgb, noisy = loaded.denoiser(rgb, image[..., 3:6], image[..., 6:9]), rgb
    if staging is None:
        return FrameResult(frame.index, seconds, _worker_name(), rgb, noisy,
                           time.perf_counter() - task_start)
    _write_frame(frame, rgb, noisy, {**metadata, "render_seconds": float(seconds)}, staging)
    return FrameResult(frame.index, seconds, _worker_name(), task_seconds=time.perf_counter() - task_start)


def _write_frame(frame: Frame, rgb: np.ndarray, noisy: np.ndarray | None,
                 metadata: dict[str, object], staging: str) -> None:
    """Write ``frame`` in a folder of its own inside ``staging``, then move
    its PNG and EXR into place (a worker killed meanwhile leaves its files
    in the staging folder, which the client removes at the end)."""
    import dataclasses

    from .tools.frames import write_frame

    folder = os.path.join(staging, f"{os.path.basename(frame.exr)[:-4]}.{os.getpid()}.{uuid.uuid4().hex[:8]}")
    try:
        os.mkdir(folder)
        try:
            staged = dataclasses.replace(frame, exr=os.path.join(folder, os.path.basename(frame.exr)),
                                         png=os.path.join(folder, os.path.basename(frame.png)))
            write_frame(staged, rgb, metadata, noisy=noisy)
            os.replace(staged.png, frame.png)
            os.replace(staged.exr, frame.exr)
        finally:
            shutil.rmtree(folder, ignore_errors=True)
    except (OSError, RuntimeError) as e:  # (OpenEXR reports a failed write as RuntimeError)
        reason = e.strerror if isinstance(e, OSError) and e.strerror else str(e)
        hint = ("; is the output folder on a filesystem the workers share? (else use --collect)"
                if not os.path.isdir(staging) else "")
        raise ClusterError(f"cannot write frame {frame.index} to {os.path.dirname(frame.exr)} on worker "
                           f"{_worker_name()}: {reason}{hint}") from None


def render_variation(spec: RenderSpec, position: int, seed: int = 0) -> Render:
    """The task of one sweep render: the scene of ``spec`` rendered with its
    first sensor (``spec.spp`` samples, None: the scene's) and ``seed``; the
    Render's ``index`` is ``position``."""
    from .cli.common import render_film

    _faults(position)
    with _render_lock:
        loaded = _load(spec, turntable=False)
        start = time.perf_counter()
        image, channels = render_film(loaded.scene, spec.spp or 0, seed, loaded.scene.integrator())
        seconds = time.perf_counter() - start
    return Render(position, {}, image, channels, seconds, _worker_name())


# -- The client's side -----------------------------------------------------------------


def worker_count(client: Client) -> int:
    """Workers connected to the scheduler now."""
    return len(client.scheduler_info().get("workers", {}))


@contextmanager
def cluster_client(scheduler: str | None = None, workers: int | None = None,
                   threads_per_worker: int = 1, connect_timeout: float = 20.0) -> Iterator[Client]:
    """A ``distributed.Client`` of the scheduler at ``scheduler``
    (``tcp://host:8786``), or of a ``LocalCluster`` of ``workers`` processes
    of ``threads_per_worker`` task threads started here (and closed with the
    block). Raises :class:`ClusterError` when ``distributed`` is missing or
    the scheduler cannot be reached."""
    import logging

    distributed = require_distributed("--scheduler" if scheduler else "--workers")
    if scheduler:
        try:
            client = distributed.Client(scheduler, timeout=connect_timeout)
        except (OSError, TimeoutError, ValueError) as e:
            raise ClusterError(f"cannot reach the Dask scheduler at {scheduler}: {e}") from None
        try:
            yield client
        finally:
            client.close()
        return
    import dask

    # (each worker's statistical profiler samples every thread's stack every
    # 10 ms: a few per cent of a frame on a busy machine)
    with dask.config.set(WORKER_CONFIG):
        cluster = distributed.LocalCluster(
            n_workers=workers, threads_per_worker=threads_per_worker, processes=True,
            dashboard_address=None, silence_logs=logging.CRITICAL,
            # (no dashboard; the scheduler's HTTP server on a free port: not 8787, which
            # another run's may hold)
            scheduler_kwargs={"dashboard_address": "127.0.0.1:0"})
    try:
        client = distributed.Client(cluster)
        try:
            yield client
        finally:
            client.close()
    finally:
        cluster.close()


def local_worker_pids(client: Client) -> list[int]:
    """The process ids of the client's LocalCluster workers (none for a
    remote scheduler's)."""
    cluster = getattr(client, "cluster", None)
    pids = []
    for worker in getattr(cluster, "workers", {}).values():
        process = getattr(worker, "process", None)
        pid = getattr(process, "pid", None)
        if pid:
            pids.append(int(pid))
    return pids


def halt(client: Client, timeout: float = 0.5) -> None:
    """Hold the event loop of ``client`` (and of its local cluster): nothing
    of Dask acts any more in this process -- no restart of a killed worker,
    no reconnection. For a process about to end (Ctrl-C): its local workers
    can then be killed without being started again."""
    loops = {id(loop): loop for loop in (getattr(client, "loop", None),
                                         getattr(getattr(client, "cluster", None), "loop", None)) if loop}
    for loop in loops.values():
        entered = threading.Event()

        def hold(entered: threading.Event = entered) -> None:
            entered.set()
            threading.Event().wait()  # (for ever: the process ends)

        try:
            loop.add_callback(hold)
        except Exception:
            continue
        entered.wait(timeout)


def stop_local_workers(client: Client, pids: Sequence[int]) -> None:
    """Ctrl-C in a command process: :func:`halt` the client's loop and kill
    the local workers ``pids`` (they would finish their frames otherwise)."""
    import signal

    halt(client)
    for pid in pids:
        try:
            os.kill(pid, signal.SIGKILL)
        except OSError:
            pass


def _describe_failure(future: Future) -> str:
    from .cli.common import root_message

    error = future.exception()
    return root_message(error) if isinstance(error, Exception) else str(error)


def completed(client: Client, futures: Sequence[Future], names: Mapping[str, str] | None = None
              ) -> Iterator[Any]:
    """The results of ``futures`` as they finish. A future in error (its
    task failed :data:`TRIES` times, or killed several workers) cancels the
    rest and raises :class:`ClusterError` with its error (``names``: the key
    -> what the task rendered, for the message). Waits in short steps, so
    Ctrl-C raises KeyboardInterrupt here at once (the futures are cancelled)."""
    distributed = require_distributed()
    pending = distributed.as_completed(futures)
    try:
        while not pending.is_empty():
            batch = pending.next_batch(block=False) if pending.has_ready() else []
            if not batch:
                time.sleep(POLL_SECONDS)
                continue
            for future in batch:
                if future.status == "error":
                    what = (names or {}).get(future.key, str(future.key))
                    message = _describe_failure(future)
                    killed = "KilledWorker" in type(future.exception()).__name__
                    why = "killed the workers that rendered it" if killed else f"failed {TRIES} times"
                    raise ClusterError(f"{what} {why}: {message}")
                if future.status == "cancelled":
                    raise ClusterError(f"{(names or {}).get(future.key, future.key)} was cancelled "
                                       "by the scheduler")
                yield future.result()
    except BaseException:
        cancel(client, futures)
        raise


def cancel(client: Client, futures: Sequence[Future], timeout: float = 2.0) -> None:
    """Cancel ``futures`` (those not finished), waiting at most ``timeout``
    seconds for the scheduler (it may be gone)."""
    unfinished = [f for f in futures if not f.done()]
    if not unfinished:
        return
    done = threading.Event()

    def run() -> None:
        try:
            client.cancel(unfinished, force=True)
        except Exception:
            pass
        finally:
            done.set()

    threading.Thread(target=run, name="lathe-cancel", daemon=True).start()
    done.wait(timeout)


def _task_key(what: str) -> str:
    return f"lathe-{what}-{uuid.uuid4().hex[:12]}"


def submit_frames(client: Client, spec: RenderSpec, frames: Iterable[tuple[Frame, dict[str, object]]],
                  staging: str | None) -> tuple[list[Future], dict[str, str]]:
    """One task per (frame, metadata) pair (:func:`render_turntable_frame`);
    returns the futures in order and the key -> ``frame K`` names."""
    futures, names = [], {}
    for frame, metadata in frames:
        key = _task_key(f"frame-{frame.index}")
        futures.append(client.submit(render_turntable_frame, spec, frame, metadata, staging, key=key,
                                     retries=TRIES - 1, pure=False))
        names[key] = f"frame {frame.index}"
    return futures, names


def variation_spec(scene_file: str | os.PathLike, variant: str, defines: Mapping[str, object] | None = None,
                   profile: str | os.PathLike | None = None, spp: int | None = None,
                   resolution: str | None = None, threads: int | None = None) -> RenderSpec:
    """The :class:`RenderSpec` of one sweep render: ``scene_file`` with the
    ``-D`` values ``defines`` and, when given, the profile file ``profile``
    for its first lathe (paths made absolute: the workers read them)."""
    items = tuple(f"{k}={v}" for k, v in (defines or {}).items())
    return RenderSpec(os.path.abspath(os.fspath(scene_file)), variant, items, resolution, spp, threads,
                      profile=None if profile is None else os.path.abspath(os.fspath(profile)))


def sweep_specs(scene_file: str | os.PathLike, variations: Iterable[Mapping[str, object] | str | os.PathLike],
                variant: str, spp: int | None = None, resolution: str | None = None,
                threads: int | None = None, defines: Mapping[str, object] | None = None
                ) -> list[tuple[dict[str, str], RenderSpec]]:
    """(variation, spec) per variation: a dict of ``-D`` values (over the
    common ``defines``), or a profile file for the scene's first lathe
    (the variation ``{"profile": path}``; :class:`ClusterError` before any
    render if it does not exist)."""
    out = []
    for variation in variations:
        merged = {str(k): str(v) for k, v in (defines or {}).items()}
        if isinstance(variation, Mapping):
            values = {str(k): str(v) for k, v in variation.items()}
            merged.update(values)
            profile = None
        else:
            profile = os.fspath(variation)
            if not os.path.isfile(profile):  # (the workers read it under the same path)
                raise ClusterError(f"profile file '{profile}' not found")
            values = {"profile": profile}
        out.append((values, variation_spec(scene_file, variant, merged, profile, spp, resolution, threads)))
    return out


def iter_renders(specs: Sequence[tuple[dict[str, str], RenderSpec]], client: Client | None = None,
                 seed: int = 0) -> Iterator[Render]:
    """The renders of ``specs`` (see :func:`sweep_specs`) as they finish: on
    the cluster of ``client``, or one after another in this process when
    ``client`` is None."""
    if client is None:
        for position, (values, spec) in enumerate(specs):
            render = _one_local(spec, position, seed)
            render.variation, render.defines = values, dict(d.split("=", 1) for d in spec.defines)
            yield render
        return
    futures, names = [], {}
    for position, (values, spec) in enumerate(specs):
        key = _task_key(f"render-{position}")
        futures.append(client.submit(render_variation, spec, position, seed, key=key,
                                     retries=TRIES - 1, pure=False))
        label = ", ".join(f"{k}={v}" for k, v in values.items())
        names[key] = f"render {position} ({label})" if label else f"render {position}"
    for render in completed(client, futures, names):
        values, spec = specs[render.index]
        render.variation, render.defines = values, dict(d.split("=", 1) for d in spec.defines)
        yield render


def _one_local(spec: RenderSpec, position: int, seed: int) -> Render:
    """A sweep render in this process (the renders in turn, no cluster)."""
    import drjit as dr

    from .tools.scenes import SceneError

    last: Exception | None = None
    threads = dr.thread_count()
    try:
        for _ in range(TRIES):
            if spec.threads is not None:
                dr.set_thread_count(spec.threads)
            try:
                return render_variation(spec, position, seed)
            except SceneError as e:
                last = e
    finally:
        if dr.thread_count() != threads:  # (this process's own count, for what it does next)
            dr.set_thread_count(threads)
    raise ClusterError(f"render {position} failed {TRIES} times: {last}")


def render_many(scene_file: str | os.PathLike,
                variations: Iterable[Mapping[str, object] | str | os.PathLike],
                client: Client | None = None, *, spp: int | None = None, resolution: str | None = None,
                seed: int = 0, variant: str = "llvm_ad_rgb", threads: int | None = None,
                defines: Mapping[str, object] | None = None) -> list[Render]:
    """Render ``scene_file`` once per variation -- a dict of ``-D``
    parameters (``{"mesh_segments": 64, "max_depth": 8}``) or a profile file
    (CSV/JSON) for the scene's first lathe -- on the Dask cluster of
    ``client`` (in this process, one after another, when None). ``spp``,
    ``resolution`` (``"WxH"`` or ``"N"``), ``seed``, ``variant`` and the
    Dr.Jit ``threads`` per worker apply to every render, as do the common
    ``-D`` ``defines``. Returns the :class:`Render` of each variation, in
    the order given; a render that fails twice raises
    :class:`ClusterError`. The scene and profile files must be readable by
    the workers under the same (absolute) paths. A ``ValueError`` for
    arguments of the wrong kind, before anything renders."""
    if isinstance(variations, (Mapping, str, bytes, os.PathLike)):
        raise ValueError("render_many: 'variations' must be a list of variations (dicts of -D values or "
                         f"profile files), got {type(variations).__name__}: wrap a single one in a list")
    if spp is not None and (isinstance(spp, bool) or not isinstance(spp, numbers.Integral) or spp < 1):
        raise ValueError(f"render_many: 'spp' must be a whole number >= 1 or None, got {spp!r}")
    if isinstance(resolution, numbers.Integral) and not isinstance(resolution, bool):
        resolution = str(resolution)  # (a square film, as "N")
    if resolution is not None and not isinstance(resolution, str):
        raise ValueError(f"render_many: 'resolution' must be 'WxH', 'N' or None, got {resolution!r}")
    specs = sweep_specs(scene_file, variations, variant, spp, resolution, threads, defines)
    renders = sorted(iter_renders(specs, client, seed), key=lambda r: r.index)
    return renders


def product(grid: Mapping[str, Sequence[str]]) -> list[dict[str, str]]:
    """Every combination of ``{key: [values]}`` as ``-D`` dicts, the last
    key varying fastest."""
    keys = list(grid)
    return [dict(zip(keys, combo, strict=True)) for combo in itertools.product(*(grid[k] for k in keys))]
