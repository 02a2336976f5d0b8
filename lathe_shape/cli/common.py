"""What every command-line tool and script shares: the option convention,
scene opening with variant selection, error reporting without tracebacks,
and the progress bar.

One module per job, every name importable from here too:
:mod:`.options` (the options and their checks), :mod:`.errors` (user errors
and one-line messages), :mod:`.variants` (``--variant``),
:mod:`.scene_input` (opening the scene, checking its sensor),
:mod:`.budget` (memory and sample limits), :mod:`.workers` (interruptible
renders in worker threads), :mod:`.output` (output folder, staged writes,
progress bar). Here: rendering a film (:func:`render_image`,
:func:`render_film`) and running a command (:func:`run_command`).

The convention (docs/cli.md):

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
import signal
import sys
import threading
from collections.abc import Callable

import numpy as np

from ..memory import available_memory, format_bytes
from . import interrupts, output

# The jobs of the former single module, one module each; their names stay
# importable from here.
from .budget import FILM_BYTES_PER_PIXEL, MAX_SAMPLES, MEMORY_FRACTION, check_render_budget
from .errors import _USER_ERRORS, CliError, error_message, is_interrupt, root_message  # noqa: F401
from .options import (  # noqa: F401
    DEFAULT_VARIANT,
    UINT32_MAX,
    _number,
    add_output_option,
    add_render_options,
    check_at_least,
    check_between,
    check_render_options,
    command_parser,
    parse_defines,
    parse_resolution,
)
from .output import ProgressBar, format_duration, output_folder, write_staged
from .scene_input import check_sensor, open_scene
from .variants import _BACKEND_NEEDS, _check_backend, select_variant  # noqa: F401
from .workers import (  # noqa: F401
    _all_work_done,
    _jit_flags,
    _reclaim_ctrl_c,
    _set_jit_flags,
    _unfinished_work,
    interruptible,
    one_render_thread,
)

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
    "one_render_thread",
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
        interrupts.print_message(f"{prog}: interrupted")
    finally:
        if main_thread and _all_work_done():  # the process goes on: main() was called in-process
            signal.signal(signal.SIGINT, handler)
    return 130


class _ClosedPipeSafe:
    """A command's standard output (or error) that outlives its reader:
    once the reader has gone (``lathe-profile --from-pov f.pov | head -1``),
    what the command prints there goes nowhere and the command finishes its
    work (its files), instead of stopping at the next print with "Broken
    pipe"."""

    def __init__(self, stream) -> None:
        self._stream = stream
        self._gone = False

    def write(self, text: str) -> int:
        if not self._gone:
            try:
                return self._stream.write(text)
            except BrokenPipeError:
                self._reader_gone()
        return len(text)

    def flush(self) -> None:
        if not self._gone:
            try:
                self._stream.flush()
            except BrokenPipeError:
                self._reader_gone()

    def _reader_gone(self) -> None:
        self._gone = True
        # The interpreter flushes the stream at exit: point its descriptor
        # at /dev/null, so that this flush cannot fail either
        try:
            null = os.open(os.devnull, os.O_WRONLY)
            os.dup2(null, self._stream.fileno())
            os.close(null)
        except (OSError, ValueError):
            pass

    def __getattr__(self, name: str):
        return getattr(self._stream, name)


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
    if argv is None:  # (a command process: its output streams may be pipes)
        if sys.stdout is not None and not isinstance(sys.stdout, _ClosedPipeSafe):
            sys.stdout = _ClosedPipeSafe(sys.stdout)
        if sys.stderr is not None and not isinstance(sys.stderr, _ClosedPipeSafe):
            sys.stderr = _ClosedPipeSafe(sys.stderr)
    created = output.created_folders.copy()
    try:
        status = body(parser.parse_args(argv))
    except SystemExit:
        raise  # argparse: --help, or a usage error already reported
    except BaseException as e:
        status = _report(prog, e)
    if status != 0:
        output.remove_empty_created(created)  # (a run that failed leaves no empty output folder)
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
