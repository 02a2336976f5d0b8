"""What commands write and show: the output folder (:func:`output_folder`),
files written whole or not at all (:func:`write_staged`), durations and the
progress bar."""

from __future__ import annotations

import errno
import os
import sys
import threading
import time
from collections.abc import Callable
from typing import TextIO

from . import interrupts
from .errors import CliError

__all__ = ["ProgressBar", "format_duration", "output_folder", "write_staged"]


#: The output folders this process created (see :func:`remove_empty_created`).
created_folders: set[str] = set()


def remove_empty_created(before: set[str]) -> None:
    """Remove the output folders created since ``before`` (a copy of
    :data:`created_folders`) that are still empty: a command that failed
    after making its folder (an unreachable cluster, say) leaves none."""
    for path in created_folders - before:
        try:
            os.rmdir(path)  # (only an empty folder)
        except OSError:
            pass
        created_folders.discard(path)


def output_folder(path: str | os.PathLike) -> str:
    """Create the folder ``path`` if missing and check that files can be
    created in it (by creating one: ``os.access`` says yes to root even on a
    read-only mount); returns its absolute path."""
    path = os.path.abspath(os.fspath(path))
    if not os.path.exists(path):
        created_folders.add(path)
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
        # (a folder that exists but takes no files, such as /proc, answers "no such file")
        why = "files cannot be created in it" if e.errno == errno.ENOENT and os.path.isdir(path) else \
            (e.strerror or str(e))
        raise CliError(f"cannot write to output folder '{path}' ({why})") from None
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
        try:
            return staging.commit(names)
        except OSError as e:  # (a folder of an output's name, say): name the output, not the staging
            target = e.filename2 or e.filename or folder
            if str(target).startswith(os.path.join(folder, ".lathe-")):
                target = os.path.join(folder, os.path.basename(str(target)))
            raise CliError(f"cannot write '{target}' ({e.strerror})") from None


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
