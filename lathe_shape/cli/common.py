"""What every command-line tool and script shares: the option convention,
scene opening with variant selection, error reporting without tracebacks,
and the progress bar.

The convention (the README's "Command line" section):

* ``-o/--output DIR`` -- the folder that receives everything a command
  writes, created if missing (``lathe-render``: the current folder;
  ``lathe-turntable`` / ``lathe-compare``: ``SCENE_turntable`` /
  ``SCENE_compare`` in the current folder);
* ``--spp N``, ``--resolution WxH`` (or ``N`` for a square), ``--seed S``;
* ``--variant NAME`` -- the Mitsuba variant (default ``llvm_ad_rgb``);
* ``-D KEY=VALUE`` -- set an XML ``<default>``, as Mitsuba's own CLI does.

A user error prints ``PROG: error: MESSAGE`` (no traceback) and exits with
status 2; Ctrl-C exits with status 130 after a one-line message. No input
gives a traceback: any other exception (``MemoryError``, an overflow, ...)
is reported the same way, with its type named (``PROG: error: MemoryError:
...``), and the environment variable ``LATHE_TRACEBACK=1`` shows its
traceback for debugging.

In a command process Ctrl-C belongs to a watcher thread (see
:mod:`.interrupts`): SIGINT is blocked in every thread, so neither Python's
handler nor the one Mitsuba installs during each render ever runs, and the
watcher ends the process (status 130, ``os._exit``: a running kernel cannot
be cancelled) within a fraction of a second at any moment, after removing
the files being written: output files are written in a hidden staging
folder and moved into place when complete, all files of one output at once
(:func:`write_staged`), so an interrupted command leaves no partial output.

Called in-process (``main(argv)``), Ctrl-C raises KeyboardInterrupt: renders
then run in a worker thread (:func:`interruptible`) while the main thread
waits in steps of a tenth of a second, since Python runs its Ctrl-C handler
only in the main thread between bytecodes.

Scene values are checked like the options (:func:`check_sensor`): a film of
width or height 0, or a sampler of 0 samples per pixel (without ``--spp``),
is refused naming the file and the parameter.

Limits checked before a render (:func:`check_render_budget`):

* ``--spp`` and ``--seed`` are 32-bit unsigned integers (Mitsuba's types):
  ``--spp`` in 1 .. 2**32 - 1, ``--seed`` in 0 .. 2**32 - 1;
* memory: a render needs about :data:`FILM_BYTES_PER_PIXEL` bytes per film
  pixel (the image block's channels, the developed image and its NumPy
  copy), whatever the sample count -- Mitsuba's JIT variants trace every
  sample of a pass in one kernel whose per-sample state stays in registers.
  A film whose estimate exceeds :data:`MEMORY_FRACTION` of the memory
  available now (``MemAvailable`` in ``/proc/meminfo``, else the free
  physical pages) is refused with the estimate, instead of being killed by
  the system when it runs out of memory;
* samples: at most :data:`MAX_SAMPLES` (2**32 - 2**24) film pixels times
  samples per pixel in one render. Mitsuba allows 2**32 samples in one pass
  and splits a larger render into passes, but with Mitsuba 3.9.1 and Dr.Jit
  1.5 (``llvm_ad_rgb``) a render of 2**32 - 256 samples comes out black
  without an error, one of 2**32 runs out of memory, and a render split into
  passes crashes; 2**32 - 2**24 samples render correctly. A render over the
  limit is refused with the largest ``--spp`` that fits: render several
  times with different ``--seed`` values and average the images instead.
"""

from __future__ import annotations

import argparse
import os
import queue
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import TextIO, TypeVar

import numpy as np

from ..memory import available_memory, format_bytes
from . import interrupts

__all__ = [
    "DEFAULT_VARIANT",
    "FILM_BYTES_PER_PIXEL",
    "MAX_SAMPLES",
    "MEMORY_FRACTION",
    "UINT32_MAX",
    "CliError",
    "ProgressBar",
    "add_output_option",
    "add_render_options",
    "available_memory",
    "check_at_least",
    "check_between",
    "check_render_budget",
    "check_render_options",
    "check_sensor",
    "command_parser",
    "error_message",
    "film_channels",
    "format_bytes",
    "format_duration",
    "interruptible",
    "is_interrupt",
    "open_scene",
    "output_folder",
    "parse_defines",
    "parse_resolution",
    "render_film",
    "render_image",
    "root_message",
    "run_command",
    "select_variant",
    "write_staged",
]

#: The variant every command uses unless ``--variant`` says otherwise.
DEFAULT_VARIANT = "llvm_ad_rgb"

#: Largest sample count and seed (Mitsuba passes both as 32-bit unsigned).
UINT32_MAX = 2**32 - 1

#: Memory a render needs per film pixel, in bytes: the film's image block
#: (RGB, alpha, weight: 5 float32), the developed image (4 float32) and its
#: (H, W, 3) float32 NumPy copy, rounded up (measured: about 30 bytes).
FILM_BYTES_PER_PIXEL = 48

#: A render whose memory estimate exceeds this fraction of the available
#: memory is refused.
MEMORY_FRACTION = 0.8

#: Samples (pixels x spp) one render may take: Mitsuba 3.9.1's LLVM variants
#: silently render a black image a little below 2**32 samples and crash when
#: Mitsuba splits a larger render into passes; this many render correctly.
MAX_SAMPLES = 2**32 - 2**24

_Result = TypeVar("_Result")


class CliError(Exception):
    """A user error: :func:`run_command` prints ``PROG: error: MESSAGE`` and
    exits with status 2, without a traceback."""


def command_parser(prog: str, description: str,
                   scene_help: str = "Mitsuba XML scene file") -> argparse.ArgumentParser:
    """The parser of a command that takes one scene file as its first argument."""
    parser = argparse.ArgumentParser(prog=prog, description=description)
    parser.add_argument("scene", help=scene_help)
    return parser


def add_output_option(parser: argparse.ArgumentParser, default: str | None = "out", what: str = "",
                      default_help: str | None = None) -> None:
    """``-o/--output DIR``: the folder for everything the command writes.

    ``default_help`` describes a default the command computes itself (e.g.
    from the scene's name): the option is then optional, ``None`` when not
    given, whatever ``default`` says."""
    if default_help is not None:
        default, where = None, f"default: {default_help}"
    else:
        where = f"default: {default}" if default else "required"
    parser.add_argument(
        "-o", "--output", metavar="DIR", default=default,
        required=default is None and default_help is None,
        help=f"output folder, created if missing{': ' + what if what else ''} ({where})",
    )


def add_render_options(parser: argparse.ArgumentParser, seed_help: str = "sampler seed (default: 0)",
                       spp_default: int | None = None, resolution_default: str | None = None,
                       defines: bool = True, seed_default: int = 0, spp_help: str | None = None,
                       resolution_help: str | None = None) -> None:
    """``--spp``, ``--resolution``, ``--seed``, ``--variant`` and (unless
    ``defines`` is False, for scenes built in Python) ``-D``. ``spp_help`` and
    ``resolution_help`` replace the default named in the help text (for
    commands that choose their own defaults)."""
    spp_help = spp_help or spp_default or "the scene's sampler"
    size_help = resolution_help or resolution_default or "the scene's film"
    parser.add_argument("--spp", type=int, default=spp_default,
                        help=f"samples per pixel (default: {spp_help})")
    parser.add_argument("--resolution", metavar="WxH", default=resolution_default,
                        help=f"film resolution, e.g. 640x480, or 512 for a square (default: {size_help})")
    parser.add_argument("--seed", type=int, default=seed_default, help=seed_help)
    parser.add_argument("--variant", default=DEFAULT_VARIANT,
                        help=f"Mitsuba variant (default: {DEFAULT_VARIANT})")
    if defines:
        parser.add_argument(
            "-D", dest="defines", action="append", metavar="KEY=VALUE",
            help="set an XML <default> parameter, e.g. -D integrator=lathe_path (repeatable)",
        )


def _number(value: float) -> str:
    """``value`` as the user would write it (``%g`` for floats; integers in
    full: ``%g`` of an integer beyond the float range raises OverflowError)."""
    return f"{value:g}" if isinstance(value, float) else str(value)


def check_at_least(option: str, value: float | None, minimum: float) -> None:
    """Raise :class:`CliError` unless ``value`` (when given) is >= ``minimum``."""
    if value is not None and not value >= minimum:
        raise CliError(f"{option} must be at least {_number(minimum)}, got {_number(value)}")


def check_between(option: str, value: float | None, minimum: float, maximum: float) -> None:
    """Raise :class:`CliError` unless ``value`` (when given) is in
    [``minimum``, ``maximum``]."""
    check_at_least(option, value, minimum)
    if value is not None and not value <= maximum:
        raise CliError(f"{option} must be at most {_number(maximum)}, got {_number(value)}")


def parse_defines(items: list[str] | None) -> dict[str, str]:
    """``["key=value", ...]`` (the ``-D`` options) -> dict."""
    defines: dict[str, str] = {}
    for item in items or []:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise CliError(f"-D expects key=value, got {item!r}")
        defines[key.strip()] = value
    return defines


def parse_resolution(text: str) -> tuple[int, int]:
    """``"WxH"`` or ``"N"`` (square) -> (width, height)."""
    parts = text.lower().split("x")
    try:
        values = [int(p) for p in parts]
    except ValueError:
        values = []
    if len(values) == 1:
        values = values * 2
    if len(values) != 2 or min(values) < 1:
        raise CliError(f"--resolution must look like 640x480 or 512, got {text!r}")
    if max(values) > UINT32_MAX:
        raise CliError(f"--resolution {text!r} is too large: at most {UINT32_MAX} pixels a side")
    return values[0], values[1]


def root_message(error: BaseException) -> str:
    """The innermost cause's message: ``mi.render`` wraps an integrator's
    error in Dr.Jit's "error while performing a custom ... operation"."""
    while error.__cause__ is not None:
        error = error.__cause__
    return str(error)


def is_interrupt(error: BaseException | None) -> bool:
    """Ctrl-C, possibly wrapped: a KeyboardInterrupt raised inside
    ``mi.render`` reaches us as the cause of Dr.Jit's RuntimeError."""
    seen = set()
    while error is not None and id(error) not in seen:
        if isinstance(error, KeyboardInterrupt):
            return True
        seen.add(id(error))
        error = error.__cause__ or error.__context__
    return False


#: The exception types whose message is itself the explanation for the user.
_USER_ERRORS = (CliError, RuntimeError, ValueError, OSError)


def error_message(error: BaseException) -> str:
    """What ``PROG: error: ...`` says about ``error``: the innermost cause's
    message (:func:`root_message`) for user errors; for any other exception
    (e.g. ``MemoryError``, whose message is often empty) its type as well."""
    message = root_message(error)
    if isinstance(error, _USER_ERRORS):
        return message
    root = error
    while root.__cause__ is not None:
        root = root.__cause__
    name = type(root).__name__
    return f"{name}: {message}" if message else name


#: What the variants of each Dr.Jit backend need: prefix -> (backend name, what).
_BACKEND_NEEDS = {"cuda_": ("CUDA", "a CUDA GPU"), "llvm_": ("LLVM", "the LLVM library (libLLVM)")}


def _check_backend(variant: str) -> None:
    """Raise :class:`SceneError` when ``variant``'s Dr.Jit backend (CUDA,
    LLVM) cannot run here, instead of Dr.Jit's error at the first kernel
    (``jit_init_thread_state(): the CUDA backend hasn't been initialized``);
    a CUDA variant's message proposes the LLVM one."""
    import drjit as dr
    import mitsuba as mi

    from ..tools.scenes import SceneError

    for prefix, (backend, what) in _BACKEND_NEEDS.items():
        if variant.startswith(prefix) and not dr.has_backend(getattr(dr.JitBackend, backend)):
            cpu = "llvm_" + variant[len(prefix):]
            instead = f" (use {cpu})" if prefix == "cuda_" and cpu in mi.variants() else ""
            raise SceneError(f"variant '{variant}' needs {what}, and none was found{instead}")


def select_variant(variant: str) -> None:
    """Select the Mitsuba ``variant`` and register the package's plugins for
    it; raises :class:`SceneError` naming the available variants, or saying
    that the variant's backend (a CUDA GPU, LLVM) is missing."""
    import mitsuba as mi

    from ..tools.scenes import SceneError

    if variant not in mi.variants():
        raise SceneError(f"unknown variant '{variant}' (available: {', '.join(mi.variants())})")
    _check_backend(variant)
    try:
        mi.set_variant(variant)
        import lathe_shape

        lathe_shape.register()
    except (RuntimeError, ImportError) as e:
        raise SceneError(str(e)) from None


def open_scene(
    path: str | os.PathLike,
    variant: str,
    defines: list[str] | None = None,
    resolution: str | None = None,
    extra_defines: dict[str, str] | None = None,
    edit: Callable[[str, str], str] | None = None,
) -> object:
    """What every command-line tool does first: select ``variant``, register
    the plugins, parse ``-D key=value`` items and a ``WxH`` resolution, load
    the scene (edited by ``edit(text, path)``, see
    :func:`..tools.scenes.load_scene`). Raises :class:`SceneError` with a
    clear message."""
    from ..tools.scenes import load_scene

    select_variant(variant)
    values = parse_defines(defines)
    values.update(extra_defines or {})
    size = parse_resolution(resolution) if resolution else None
    return load_scene(path, values, size, edit)


def check_render_options(args: argparse.Namespace) -> None:
    """Check the options of :func:`add_render_options` before anything is
    loaded: ``--spp`` and ``--seed`` in their 32-bit ranges, the syntax of
    ``--resolution`` and of each ``-D``. Raises :class:`CliError` naming the
    option."""
    check_between("--spp", args.spp, 1, UINT32_MAX)
    check_between("--seed", args.seed, 0, UINT32_MAX)
    if args.resolution is not None:
        parse_resolution(args.resolution)
    parse_defines(getattr(args, "defines", None))


def check_sensor(scene, path: str | os.PathLike, spp: int | None = None) -> tuple[int, int, int]:
    """(width, height, samples per pixel) of the first sensor of ``scene``
    (loaded from the file ``path``): ``spp`` (the ``--spp`` option), or
    the sampler's ``sample_count`` when None. Raises :class:`CliError`
    naming the file and the parameter when the scene has no sensor, when
    its film is 0 pixels wide or high, or when its sampler takes 0 samples
    per pixel (Mitsuba would fail in a kernel, or crash)."""
    if not scene.sensors():
        raise CliError(f"{os.fspath(path)}: the scene has no sensor")
    sensor = scene.sensors()[0]
    width, height = (int(v) for v in sensor.film().size())
    for name, value in (("width", width), ("height", height)):
        if value < 1:
            raise CliError(f"{os.fspath(path)}: the film's '{name}' is {value}: it must be at least 1 "
                           "(fix the scene, or set --resolution)")
    if spp is None:
        spp = int(sensor.sampler().sample_count())
        if spp < 1:
            raise CliError(f"{os.fspath(path)}: the sampler's 'sample_count' is {spp}: it must be at "
                           "least 1 (fix the scene, or set --spp)")
    return width, height, int(spp)


def check_render_budget(width: int, height: int, spp: int, available: int | None = None) -> None:
    """Refuse a render of ``spp`` samples per pixel on a ``width`` x ``height``
    film that cannot run correctly: more memory than :data:`MEMORY_FRACTION`
    of ``available`` (default: :func:`available_memory`), or more than
    :data:`MAX_SAMPLES` samples (the rules are in this module's docstring).
    Raises :class:`CliError` with the numbers."""
    width, height, spp = int(width), int(height), int(spp)
    pixels = width * height
    needed = pixels * FILM_BYTES_PER_PIXEL
    available = available_memory() if available is None else available
    if available is not None and needed > MEMORY_FRACTION * available:
        raise CliError(
            f"a {width}x{height} film needs about {format_bytes(needed)} of memory, more than "
            f"{MEMORY_FRACTION:.0%} of the {format_bytes(available)} available: use a smaller --resolution")
    if pixels > MAX_SAMPLES:
        raise CliError(f"a {width}x{height} film has more pixels than the {MAX_SAMPLES} samples one render "
                       "can take: use a smaller --resolution")
    if pixels * spp > MAX_SAMPLES:
        raise CliError(
            f"{spp} spp on a {width}x{height} film is {pixels * spp} samples, more than the {MAX_SAMPLES} "
            f"one render can take: use at most --spp {MAX_SAMPLES // pixels} (or average renders with "
            "different --seed values)")


def _reclaim_ctrl_c() -> None:
    """Give Ctrl-C back to Python. Mitsuba's render installs a C signal
    handler of its own (unseen by ``signal.getsignal``), which only asks the
    render to wind down after its kernel has finished, tens of seconds
    later."""
    signal.signal(signal.SIGINT, signal.default_int_handler)


def interruptible(function: Callable[..., _Result], *args: object) -> _Result:
    """``function(*args)`` run in a worker thread while the main thread waits
    in short steps, so that Ctrl-C raises KeyboardInterrupt here within a
    fraction of a second even while ``function`` runs a long Dr.Jit kernel.
    The worker then goes on running (a kernel cannot be cancelled):
    :func:`run_command` ends the process after its message. Called outside
    the main thread, just calls ``function``.

    The worker is a new thread per call, or inside :func:`one_render_thread`
    that block's one thread (Dr.Jit sets up per-thread state, on CUDA a
    stream, for every new thread: a cost a turntable would pay per frame)."""
    if threading.current_thread() is not threading.main_thread():
        return function(*args)
    outcome: dict[str, object] = {}
    done = threading.Event()  # (not Thread.join: a join interrupted by Ctrl-C marks the thread stopped)
    flags = _jit_flags()

    def work() -> None:
        try:
            _set_jit_flags(flags)
            outcome["value"] = function(*args)
        except BaseException as e:  # re-raised in the calling thread
            outcome["error"] = e
        finally:
            done.set()

    if _render_thread is not None:
        _render_thread.put(work)
    else:
        threading.Thread(target=work, name="lathe-worker", daemon=True).start()
    try:
        while not done.wait(0.1):
            _reclaim_ctrl_c()
    except BaseException:
        _unfinished_work.append(done)
        raise
    # Mitsuba puts Python's handler back when its render ends, but with
    # SA_RESTART: a blocking wait (a lock, a full queue) would then sleep
    # through Ctrl-C.
    _reclaim_ctrl_c()
    if "error" in outcome:
        raise outcome["error"]
    return outcome["value"]


#: The jobs queue of the thread that :func:`one_render_thread` keeps, if any.
_render_thread: queue.SimpleQueue | None = None


@contextmanager
def one_render_thread() -> Iterator[None]:
    """Within the block, :func:`interruptible` runs every call on one thread
    (in order), which ends with the block (after a call abandoned by Ctrl-C,
    when that call ends)."""
    global _render_thread
    previous, jobs = _render_thread, queue.SimpleQueue()

    def serve() -> None:
        while (job := jobs.get()) is not None:
            job()

    threading.Thread(target=serve, name="lathe-worker", daemon=True).start()
    _render_thread = jobs
    try:
        yield
    finally:
        _render_thread = previous
        jobs.put(None)


def _jit_flags() -> dict[object, bool]:
    """The calling thread's Dr.Jit flags (they are per thread), if Dr.Jit is loaded."""
    if "drjit" not in sys.modules:
        return {}
    import drjit as dr

    return {flag: dr.flag(flag) for flag in dr.JitFlag if flag != dr.JitFlag.Default}


def _set_jit_flags(flags: dict[object, bool]) -> None:
    """Give this thread the Dr.Jit ``flags`` of :func:`_jit_flags`."""
    if not flags:
        return
    import drjit as dr

    for flag, value in flags.items():
        if dr.flag(flag) != value:
            dr.set_flag(flag, value)


def render_image(scene, spp: int, seed: int, integrator):
    """``mi.render(scene, spp=spp, seed=seed, integrator=integrator)`` as an
    (H, W, C) NumPy array, rendered in an :func:`interruptible` worker."""
    import mitsuba as mi

    return interruptible(lambda: mi.render(scene, spp=spp, seed=seed, integrator=integrator).numpy())


def film_channels(film, image: np.ndarray) -> tuple[np.ndarray, list[str]]:
    """(pixels, channel names) of ``film`` after a render that returned
    ``image``: the names Mitsuba gives the film's channels (``R``, ``G``,
    ``B``[, ``A``], or ``Y`` for a luminance film, then the integrator's AOVs
    as in its ``aov_names()``, e.g. ``albedo.R``), read from ``film.bitmap()``
    as Mitsuba's own writer does. ``image`` is kept as rendered unless it
    lacks channels the film holds (Mitsuba's ``aov`` integrator with a nested
    integrator returns fewer than it stores): the film's bitmap then."""
    bitmap = film.bitmap()
    names = [bitmap.struct_()[index].name for index in range(bitmap.channel_count())]
    if len(names) == image.shape[-1]:
        return image, names
    return np.asarray(bitmap, dtype=np.float32), names


def render_film(scene, spp: int, seed: int, integrator) -> tuple[np.ndarray, list[str]]:
    """:func:`render_image` with the channel names of the scene's first film
    (:func:`film_channels`): (pixels (H, W, C), names)."""
    image = render_image(scene, spp, seed, integrator)
    return film_channels(scene.sensors()[0].film(), image)


#: The completion events of :func:`interruptible` workers left running after Ctrl-C.
_unfinished_work: list[threading.Event] = []


def output_folder(path: str | os.PathLike) -> str:
    """Create the folder ``path`` if missing and check that files can be
    created in it (by creating one: ``os.access`` says yes to root even on a
    read-only mount); returns its absolute path."""
    path = os.path.abspath(os.fspath(path))
    if os.path.exists(path) and not os.path.isdir(path):
        raise CliError(f"output folder '{path}' exists and is not a folder")
    probe = os.path.join(path, f".write-test-{os.getpid()}-{threading.get_ident()}")

    def remove_probe() -> None:
        if os.path.exists(probe):
            os.remove(probe)

    try:
        with interrupts.on_interrupt(remove_probe):
            os.makedirs(path, exist_ok=True)
            interrupts.watch_folder(path)
            try:
                os.close(os.open(probe, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o600))
            finally:
                remove_probe()
    except OSError as e:
        raise CliError(f"cannot write to output folder '{path}' ({e.strerror or e})") from None
    return path


def write_staged(folder: str, writes: list[tuple[Callable[[str], list[str]], str]]) -> list[str]:
    """Run each ``write(stem)`` of ``writes`` (which writes files named
    ``stem`` + extension and returns their paths) with ``stem`` in a hidden
    staging folder inside ``folder`` (:class:`.interrupts.Staging`), then
    move all the files into ``folder`` at once under their names (the
    ``name`` of each pair + extension). An interrupted or failed write
    leaves none of them. Returns the final paths."""
    with interrupts.Staging(folder) as staging:
        names = []
        for write, name in writes:
            for path in write(staging.stage(name)):
                names.append(os.path.basename(path))
        return staging.commit(names)


def format_duration(seconds: float) -> str:
    """``75.2`` -> ``"1:15"``; ``3725`` -> ``"1:02:05"``."""
    seconds = int(round(max(seconds, 0.0)))
    hours, rest = divmod(seconds, 3600)
    minutes, secs = divmod(rest, 60)
    return f"{hours}:{minutes:02d}:{secs:02d}" if hours else f"{minutes}:{secs:02d}"


class ProgressBar:
    """A one-line progress bar with ETA: frames done / total, elapsed time,
    and the remaining time estimated from the frames rendered so far.

    On a terminal the line is redrawn in place; otherwise (a log file, a CI
    job) one line is written per update.
    """

    def __init__(self, total: int, done: int = 0, stream: TextIO | None = None, width: int = 24) -> None:
        self.total, self.done, self.width = total, done, width
        self.stream = stream if stream is not None else sys.stderr
        self.rendered = 0
        self.render_seconds = 0.0
        self.start = time.perf_counter()
        isatty = getattr(self.stream, "isatty", None)
        self.interactive = bool(isatty and isatty())

    def eta(self) -> float | None:
        """Seconds left, from the mean time of the frames rendered so far."""
        if self.rendered == 0:
            return None
        return (self.total - self.done) * self.render_seconds / self.rendered

    def line(self) -> str:
        filled = self.width * self.done // max(self.total, 1)
        eta = self.eta()
        return (
            f"[{'#' * filled}{'.' * (self.width - filled)}] {self.done}/{self.total} frames"
            f"  elapsed {format_duration(time.perf_counter() - self.start)}"
            f"  ETA {'--:--' if eta is None else format_duration(eta)}"
        )

    def show(self) -> None:
        if self.interactive:
            self.stream.write("\r" + self.line() + "\x1b[K")
        else:
            self.stream.write(self.line() + "\n")
        self.stream.flush()

    def advance(self, seconds: float | None = None) -> None:
        """One more frame done: rendered in ``seconds``, or skipped (None)."""
        self.done += 1
        if seconds is not None:
            self.rendered += 1
            self.render_seconds += seconds
        self.show()

    def close(self) -> None:
        """End the line (terminals only)."""
        if self.interactive:
            self.stream.write("\n")
            self.stream.flush()


def _report(prog: str, error: BaseException) -> int:
    """Print the one-line message for ``error``; returns the exit status."""
    if os.environ.get("LATHE_TRACEBACK"):
        import traceback

        traceback.print_exception(error)
    if not is_interrupt(error):
        print(f"{prog}: error: {error_message(error)}", file=sys.stderr)
        return 2
    main_thread = threading.current_thread() is threading.main_thread()
    handler = signal.signal(signal.SIGINT, signal.SIG_IGN) if main_thread else None
    try:  # (a second Ctrl-C meanwhile is ignored, so that it gives no traceback)
        print(f"{prog}: interrupted", file=sys.stderr)
    finally:
        if main_thread and _all_work_done():  # the process goes on: main() was called in-process
            signal.signal(signal.SIGINT, handler)
    return 130


def _all_work_done() -> bool:
    """Whether every :func:`interruptible` worker has finished."""
    return all(done.is_set() for done in _unfinished_work)


def run_command(prog: str, parser: argparse.ArgumentParser, body: Callable[[argparse.Namespace], int],
                argv: list[str] | None = None) -> int:
    """Parse ``argv`` and run ``body(args)``; every exception becomes a
    one-line message (see :func:`error_message`): ``PROG: error: ...`` and
    status 2, or on Ctrl-C ``PROG: interrupted`` and status 130. When a
    render is still running in a worker (:func:`interruptible`), or when a
    command run from the command line was interrupted, the process ends
    here, with that status, without waiting for the render or for the
    interpreter's shutdown."""
    interrupts.set_prog(prog)  # (the watcher's message, in a command process)
    try:
        status = body(parser.parse_args(argv))
    except SystemExit:
        raise  # argparse: --help, or a usage error already reported
    except BaseException as e:
        status = _report(prog, e)
    # A command run from the command line (``argv`` None) that was
    # interrupted ends here too: a Ctrl-C that lands while Dr.Jit or
    # Mitsuba threads wind down can otherwise abort the interpreter's
    # shutdown ("terminate called without an active exception", status 134).
    if argv is None and interrupts.installed():
        # A command process ends here: a Ctrl-C during the interpreter's
        # shutdown (tenths of a second of Mitsuba and Dr.Jit teardown) would
        # otherwise be lost and the command exit 0.
        interrupts.exit(status)
    if not _all_work_done() or (status == 130 and argv is None):
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(status)
    return status
