"""Ctrl-C in the commands: a watcher thread owns SIGINT.

Mitsuba's ``mi.render`` installs a C signal handler of its own for SIGINT
while it runs (it cancels the render at the end of its kernel, prints
"Received interrupt signal, winding down.." and lets the render finish), and
puts the previous handler back when it returns. Taking the handler back
after every render leaves a window in which a Ctrl-C is Mitsuba's: with
short frames a turntable spends most of its time in that window.

So a command process (:func:`install`, called when the package is imported
by ``lathe-render`` & co., before Mitsuba is) blocks SIGINT in its main
thread before any other thread exists: every thread inherits the mask (Dr.Jit's
and Mitsuba's pools, the render and writer threads), no signal handler ever
runs for SIGINT, whichever is installed, and the signal stays pending until
the watcher thread takes it with ``sigwait``. The watcher then, within a
fraction of a second whatever the other threads do:

* lets frame writes already running (:func:`writing`) finish for up to
  :data:`GRACE_SECONDS`, and starts no new one;
* takes the commit lock (:func:`commit`: the renames of finished files
  into place), so that an output made of several files (an EXR and its PNG,
  the five files of ``lathe-compare``) is there whole or not at all;
* runs the clean-ups registered with ``on_interrupt(..., first=True)``
  (those that must act before the children end: a local Dask cluster
  would otherwise restart its killed workers);
* ends the process's children (an ``ffmpeg`` writing an MP4);
* runs the clean-ups registered with :func:`on_interrupt` (staging
  folders of unfinished files, the turntable's folder lock) and removes
  the process's temporary files in the output folders
  (:func:`watch_folder`);
* prints the command's one-line message (:func:`message`: that of the block
  the Ctrl-C came in, even if the command's threads have left it since; the
  command itself prints none, :func:`print_message`) and ends the process
  with status 130 (``os._exit``: a running kernel cannot be cancelled).

Files are written in a hidden staging folder inside the output folder
(:class:`Staging`) and moved into place by :func:`commit`. The watcher
renames the staging folder before removing it: a thread still writing then
writes into the renamed folder, and one about to create a file finds no
folder, so nothing is left behind.

Outside a command (``main(argv)`` called in-process, the tests) nothing is
installed: Ctrl-C raises KeyboardInterrupt as usual, and the staging,
commit and writing helpers work the same without a watcher.
"""

from __future__ import annotations

import itertools
import os
import shutil
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

__all__ = [
    "GRACE_SECONDS",
    "Staging",
    "commit",
    "exit",
    "install",
    "installed",
    "message",
    "on_interrupt",
    "print_message",
    "set_prog",
    "stopping",
    "watch_folder",
    "writing",
]

#: How long the watcher lets frame writes already running finish.
GRACE_SECONDS = 0.4
#: How long the watcher waits for a commit in progress (renames: microseconds).
COMMIT_WAIT_SECONDS = 0.2
#: How long the watcher waits for a killed child to end.
CHILD_WAIT_SECONDS = 0.2

_commit_lock = threading.Lock()
_exit_lock = threading.Lock()  # (whoever takes it ends the process: the watcher or exit())
_state = threading.Condition()
_writes_in_flight = 0
_stopping = False
_watcher: threading.Thread | None = None
_prog = "lathe"
_message: Callable[[], str] | None = None
_cleanups: dict[int, Callable[[], None]] = {}
_first_cleanups: dict[int, Callable[[], None]] = {}
_folders: set[str] = set()
_tokens = itertools.count()


def install(prog: str) -> None:
    """Block SIGINT in this (main) thread, and so in every thread started
    from now on, and start the watcher that takes it. Call before any other
    thread exists (before importing Mitsuba)."""
    global _watcher, _prog
    if _watcher is not None or threading.current_thread() is not threading.main_thread():
        return
    _prog = prog
    signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    _watcher = threading.Thread(target=_watch, name="lathe-ctrl-c", daemon=True)
    _watcher.start()


def installed() -> bool:
    """Whether this process's Ctrl-C is the watcher's."""
    return _watcher is not None


def stopping() -> bool:
    """Whether the watcher has taken a Ctrl-C and is ending the process (it
    prints the command's message: the command must not print its own)."""
    return _stopping


def print_message(text: str) -> None:
    """Print a command's Ctrl-C message on stderr, unless the watcher is
    ending the process: it prints the message itself (:func:`message`)."""
    if not _stopping:
        print(text, file=sys.stderr)


def set_prog(prog: str) -> None:
    """The command name of the ``PROG: interrupted`` message."""
    global _prog
    _prog = prog


@contextmanager
def message(make: Callable[[], str]) -> Iterator[None]:
    """Within the block, ``make()`` is the watcher's message (default:
    ``PROG: interrupted``)."""
    global _message
    previous, _message = _message, make
    try:
        yield
    finally:
        _message = previous


@contextmanager
def on_interrupt(cleanup: Callable[[], None], first: bool = False) -> Iterator[None]:
    """Within the block, the watcher runs ``cleanup()`` before it ends the
    process (clean-ups run newest first); with ``first``, before it ends
    the process's children."""
    if first:
        token = next(_tokens)
        _first_cleanups[token] = cleanup
    else:
        token = _register(cleanup)
    try:
        yield
    finally:
        (_first_cleanups if first else _cleanups).pop(token, None)


def watch_folder(folder: str | os.PathLike) -> None:
    """On Ctrl-C, remove this process's temporary files in ``folder``: those
    of :func:`~lathe_shape.tools.images.atomic_path` (``.NAME.PID.tmp.EXT``),
    which writes outside a :class:`Staging` folder use (e.g. animations,
    converted profiles)."""
    _folders.add(os.path.abspath(os.fspath(folder)))


def _remove_temporary_files() -> None:
    marker = f".{os.getpid()}.tmp"
    for folder in list(_folders):
        try:
            names = os.listdir(folder)
        except OSError:
            continue
        for name in names:
            if name.startswith(".") and marker in name:
                try:
                    os.remove(os.path.join(folder, name))
                except OSError:
                    pass


def _register(cleanup: Callable[[], None]) -> int:
    token = next(_tokens)
    _cleanups[token] = cleanup
    return token


@contextmanager
def writing() -> Iterator[None]:
    """A frame write the watcher lets finish (for up to
    :data:`GRACE_SECONDS`); after a Ctrl-C none starts (KeyboardInterrupt)."""
    global _writes_in_flight
    with _state:
        if _stopping:
            raise KeyboardInterrupt
        _writes_in_flight += 1
    try:
        yield
    finally:
        with _state:
            _writes_in_flight -= 1
            _state.notify_all()


def commit(moves: list[tuple[str, str]]) -> None:
    """``os.replace(source, target)`` for each pair, in order, all or none
    of them before the watcher ends the process."""
    with _commit_lock:
        for source, target in moves:
            os.replace(source, target)


class Staging:
    """A hidden folder ``.lathe-PID-N.tmp`` in ``folder`` for files being
    written; :meth:`commit` moves finished ones into ``folder``. Removed
    with its content when the ``with`` block ends or on Ctrl-C."""

    _counter = itertools.count()

    def __init__(self, folder: str | os.PathLike) -> None:
        self.folder = os.fspath(folder)
        self.path = os.path.join(self.folder, f".lathe-{os.getpid()}-{next(self._counter)}.tmp")
        self._token: int | None = None

    def __enter__(self) -> Staging:
        self._token = _register(self.discard)
        try:
            os.mkdir(self.path)
        except BaseException:
            _cleanups.pop(self._token, None)
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        try:
            self.discard()
        finally:
            _cleanups.pop(self._token, None)

    def stage(self, name: str) -> str:
        """Where to write the file that :meth:`commit` makes ``folder/name``."""
        return os.path.join(self.path, name)

    def commit(self, names: list[str]) -> list[str]:
        """Move the staged ``names`` into the folder (all or none, in order);
        returns their final paths."""
        targets = [os.path.join(self.folder, name) for name in names]
        commit([(self.stage(name), target) for name, target in zip(names, targets, strict=True)])
        return targets

    def discard(self) -> None:
        """Remove the staging folder and what it holds (renamed first: a
        thread still writing cannot create a file in it afterwards)."""
        doomed = self.path[:-len(".tmp")] + ".del"
        try:
            os.rename(self.path, doomed)
        except FileNotFoundError:
            return
        shutil.rmtree(doomed, ignore_errors=True)


def _children() -> list[int]:
    """The process ids of this process's children (Linux: /proc)."""
    found = []
    try:
        for task in os.listdir("/proc/self/task"):
            try:
                with open(f"/proc/self/task/{task}/children") as f:
                    found += [int(pid) for pid in f.read().split()]
            except OSError:
                pass
    except OSError:
        pass
    return found


def _end_children() -> None:
    children = _children()
    for pid in children:
        try:
            os.kill(pid, signal.SIGKILL)
        except OSError:
            pass
    deadline = time.monotonic() + CHILD_WAIT_SECONDS
    for pid in children:
        while time.monotonic() < deadline:
            try:
                if os.waitpid(pid, os.WNOHANG)[0]:
                    break
            except ChildProcessError:  # (reaped by its subprocess.Popen)
                break
            time.sleep(0.005)


def _write_message(make: Callable[[], str] | None) -> None:
    try:
        text = make() if make is not None else f"{_prog}: interrupted"
    except Exception:
        text = f"{_prog}: interrupted"
    # Straight to the file descriptor: a flush could wait for a pipe that
    # nobody reads, and stderr's buffer is flushed at every line anyway.
    data = (text + "\n").encode("utf-8", "replace")
    try:
        os.write(2, data)
    except OSError:
        pass


def _stop() -> None:
    """What a Ctrl-C does in a command process (see the module docstring)."""
    global _stopping
    deadline = time.monotonic() + GRACE_SECONDS
    # The message of the block running when the Ctrl-C came: the command's
    # threads may leave that block (a write refused below) before it is printed.
    make_message = _message
    _exit_lock.acquire()  # (kept: the command's own exit() no longer happens)
    with _state:
        _stopping = True
        while _writes_in_flight and (left := deadline - time.monotonic()) > 0:
            _state.wait(left)
    _commit_lock.acquire(timeout=COMMIT_WAIT_SECONDS)  # (kept: no commit after this)
    _run_cleanups(_first_cleanups)
    _end_children()
    _run_cleanups(_cleanups)
    _remove_temporary_files()
    _write_message(make_message)
    os._exit(130)


def _run_cleanups(cleanups: dict[int, Callable[[], None]]) -> None:
    """Run ``cleanups``, newest first, ignoring their errors."""
    for token in sorted(list(cleanups), reverse=True):
        cleanup = cleanups.get(token)
        try:
            if cleanup is not None:
                cleanup()
        except Exception:
            pass


def exit(status: int) -> None:  # noqa: A001 (the command's end)
    """End a command process with ``status`` now, without the interpreter's
    shutdown (a few tenths of a second, in which a Ctrl-C would go
    unanswered) -- unless a Ctrl-C came first: the watcher's status 130
    then."""
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except Exception:
            pass
    # A SIGINT the watcher has taken but not acted on yet (it waits for the
    # interpreter lock) must win: give it the lock for a moment, and wait
    # for it when the signal is still pending.
    time.sleep(0.01)
    while signal.SIGINT in signal.sigpending():
        time.sleep(0.01)
    with _exit_lock:
        os._exit(status)


def _watch() -> None:
    signal.sigwait({signal.SIGINT})
    _stop()
