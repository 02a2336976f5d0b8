"""Renders that Ctrl-C can interrupt in-process: :func:`interruptible` runs
a call in a worker thread while the main thread waits in short steps
(:func:`one_render_thread`: one worker for a block of calls); the workers
left running after Ctrl-C are tracked (:func:`_all_work_done`)."""

from __future__ import annotations

import queue
import signal
import sys
import threading
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import TypeVar

__all__ = ["interruptible", "one_render_thread"]


_Result = TypeVar("_Result")


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


#: The completion events of :func:`interruptible` workers left running after Ctrl-C.
_unfinished_work: list[threading.Event] = []


def _all_work_done() -> bool:
    """Whether every :func:`interruptible` worker has finished."""
    return all(done.is_set() for done in _unfinished_work)
