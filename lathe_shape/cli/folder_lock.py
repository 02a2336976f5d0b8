"""Who renders into a turntable's output folder: one registration file per
running ``lathe-turntable``, so that a second job cannot mix its frames into
a turn being rendered.

Each run holds a hidden file ``.lathe-turntable-PID.lock`` in the output
folder, locked (``fcntl.flock``) for as long as the process lives and
holding its process id, the job's settings (those that decide whether a
frame on disk is this job's: count, mode, spp, seed, size, ...) and its
frame range. A run starting on the folder refuses to start when a live run
registered before it renders another job there, or the same job with
overlapping ``--frames``; shards of one job (``--frames 0:18`` and ``--frames
18:36``) may run side by side, as the command's help says. A file whose lock
is free belongs to a process that died (``kill -9``, a crash): it is stale
and removed, as are that process's staging folders.

The file is written under another name, locked, and then renamed into place,
so that every registration another run sees is complete and locked. Two runs
starting at the same moment both see each other; the later registration
(file change time, then process id) is the one refused.
"""

from __future__ import annotations

import fcntl
import json
import os
import re
import shutil

from . import interrupts
from .common import CliError

__all__ = ["FolderLock"]

_REGISTRATION = re.compile(r"\.lathe-turntable-(\d+)\.lock")
_STAGING = re.compile(r"\.lathe-(\d+)-\d+\.(tmp|del)")
_UNFINISHED = re.compile(r"\.lathe-turntable-(\d+)\.lock\.new")


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # (someone else's process)
        return True
    return True


class FolderLock:
    """The registration of one run in ``folder`` (see the module
    docstring); a context manager. ``job``: the settings (JSON values)
    that make two runs the same job; ``frames``: the half-open range of
    frame indices the run renders."""

    def __init__(self, folder: str, job: dict[str, object], frames: range,
                 prog: str = "lathe-turntable") -> None:
        self.folder, self.job, self.frames, self.prog = folder, job, frames, prog
        self.path = os.path.join(folder, f".lathe-turntable-{os.getpid()}.lock")
        self._fd: int | None = None
        self._interrupt: object = None

    def __enter__(self) -> FolderLock:
        self.acquire()
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()

    def acquire(self) -> None:
        """Register this run, or raise :class:`CliError` naming the run
        that holds the folder."""
        self._interrupt = interrupts.on_interrupt(self.release)
        self._interrupt.__enter__()
        try:
            self._register()
            self._check_others()
        except BaseException:
            self.release()
            raise

    def release(self) -> None:
        """Remove the registration (the lock ends with the file's descriptor)."""
        fd, self._fd = self._fd, None
        if fd is not None:
            try:
                os.remove(self.path)
            except FileNotFoundError:
                pass
            os.close(fd)
        if self._interrupt is not None:
            interrupt, self._interrupt = self._interrupt, None
            interrupt.__exit__(None, None, None)

    def _register(self) -> None:
        record = {"pid": os.getpid(), "prog": self.prog, "job": self.job,
                  "frames": [self.frames.start, self.frames.stop]}
        new = self.path + ".new"
        fd = os.open(new, os.O_CREAT | os.O_TRUNC | os.O_RDWR, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            os.write(fd, json.dumps(record).encode("utf-8"))
            os.rename(new, self.path)
        except BaseException:
            os.close(fd)
            if os.path.exists(new):
                os.remove(new)
            raise
        self._fd = fd

    def _order(self, stat: os.stat_result, pid: int) -> tuple[int, int]:
        return stat.st_ctime_ns, pid

    def _check_others(self) -> None:
        mine = self._order(os.fstat(self._fd), os.getpid())
        for name in sorted(os.listdir(self.folder)):
            if (match := _REGISTRATION.fullmatch(name)) and int(match.group(1)) != os.getpid():
                self._check(os.path.join(self.folder, name), int(match.group(1)), mine)
            elif (match := _STAGING.fullmatch(name) or _UNFINISHED.fullmatch(name)) \
                    and not _alive(int(match.group(1))):
                path = os.path.join(self.folder, name)  # left by a process that was killed
                if os.path.isdir(path):
                    shutil.rmtree(path, ignore_errors=True)
                else:
                    _remove(path)

    def _check(self, path: str, pid: int, mine: tuple[int, int]) -> None:
        """Refuse to run when the registration ``path`` is live, earlier than
        this one, and another job's or one of overlapping frames; remove it
        when stale."""
        try:
            fd = os.open(path, os.O_RDONLY)
        except FileNotFoundError:  # (its run just ended)
            return
        try:
            try:
                fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
            except BlockingIOError:  # locked: its run is alive
                stat = os.fstat(fd)
                with os.fdopen(os.dup(fd), "rb") as f:
                    record = json.loads(f.read().decode("utf-8") or "{}")
                if self._order(stat, pid) < mine:
                    self._refuse(record, pid)
                return
            # Free: its process ended without removing it (killed). Remove it
            # unless a new run of the same process id replaced it meanwhile.
            try:
                if os.stat(path).st_ino == os.fstat(fd).st_ino:
                    os.remove(path)
            except FileNotFoundError:
                pass
        finally:
            os.close(fd)

    def _refuse(self, record: dict, pid: int) -> None:
        other_job = record.get("job", {})
        start, stop = record.get("frames", [0, 0])
        other = record.get("prog", self.prog)  # (a sweep and a turntable share the folder's registrations)
        where = f"output folder '{self.folder}' is in use by another {other} (pid {pid})"
        differs = sorted(key for key in set(other_job) | set(self.job)
                         if other_job.get(key) != self.job.get(key))
        if differs:
            raise CliError(f"{where}, which renders another job into it (other {', '.join(differs)}): "
                           "wait for it to end, or choose another -o")
        if start < self.frames.stop and self.frames.start < stop:
            raise CliError(f"{where}, which renders frames {start}:{stop} of this turn: wait for it to end, "
                           "or render other --frames")


def _remove(path: str) -> None:
    try:
        os.remove(path)
    except FileNotFoundError:
        pass
