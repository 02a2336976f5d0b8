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
status 2; Ctrl-C exits with status 130 after a one-line message.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from collections.abc import Callable
from typing import TextIO

__all__ = [
    "DEFAULT_VARIANT",
    "CliError",
    "ProgressBar",
    "add_output_option",
    "add_render_options",
    "check_at_least",
    "command_parser",
    "format_duration",
    "is_interrupt",
    "open_scene",
    "output_folder",
    "parse_defines",
    "parse_resolution",
    "root_message",
    "run_command",
    "select_variant",
]

#: The variant every command uses unless ``--variant`` says otherwise.
DEFAULT_VARIANT = "llvm_ad_rgb"


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


def check_at_least(option: str, value: float | None, minimum: float) -> None:
    """Raise :class:`CliError` unless ``value`` (when given) is >= ``minimum``."""
    if value is not None and not value >= minimum:
        raise CliError(f"{option} must be at least {minimum:g}, got {value:g}")


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
        raise CliError(f"resolution must look like 640x480 or 512, got {text!r}")
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


def select_variant(variant: str) -> None:
    """Select the Mitsuba ``variant`` and register the package's plugins for
    it; raises :class:`SceneError` naming the available variants."""
    import mitsuba as mi

    from ..tools.scenes import SceneError

    if variant not in mi.variants():
        raise SceneError(f"unknown variant '{variant}' (available: {', '.join(mi.variants())})")
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
) -> object:
    """What every command-line tool does first: select ``variant``, register
    the plugins, parse ``-D key=value`` items and a ``WxH`` resolution, load
    the scene. Raises :class:`SceneError` with a clear message."""
    from ..tools.scenes import load_scene

    select_variant(variant)
    values = parse_defines(defines)
    values.update(extra_defines or {})
    size = parse_resolution(resolution) if resolution else None
    return load_scene(path, values, size)


def output_folder(path: str | os.PathLike) -> str:
    """Create the folder ``path`` if missing and check that files can be
    created in it (by creating one: ``os.access`` says yes to root even on a
    read-only mount); returns its absolute path."""
    path = os.path.abspath(os.fspath(path))
    if os.path.exists(path) and not os.path.isdir(path):
        raise CliError(f"output folder '{path}' exists and is not a folder")
    try:
        os.makedirs(path, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=path, prefix=".write-test-"):
            pass
    except OSError as e:
        raise CliError(f"cannot write to output folder '{path}' ({e.strerror or e})") from None
    return path


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


def run_command(prog: str, parser: argparse.ArgumentParser, body: Callable[[argparse.Namespace], int],
                argv: list[str] | None = None) -> int:
    """Parse ``argv`` and run ``body(args)``; user errors (:class:`CliError`,
    scene and profile errors, a failed render) print ``PROG: error: ...``
    and return 2, Ctrl-C prints ``PROG: interrupted`` and returns 130."""
    args = parser.parse_args(argv)
    try:
        return body(args)
    except (CliError, KeyboardInterrupt, RuntimeError, ValueError, OSError) as e:
        if is_interrupt(e):
            print(f"{prog}: interrupted", file=sys.stderr)
            return 130
        print(f"{prog}: error: {root_message(e)}", file=sys.stderr)
        return 2
