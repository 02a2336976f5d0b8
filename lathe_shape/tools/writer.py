"""Background threads that finish frames (denoise, EXR and PNG writes)
while the next frame renders, so a turntable runs at the speed of the render
itself.

On a GPU a frame renders in about the time one thread takes to encode it
(sRGB conversion, ZIP-compressed EXR, PNG), so several ``workers`` share the
queue; each job writes files of its own, and the encoders release the GIL.
At most ``depth`` frames wait in the queue, which bounds the memory held and
makes the renderer wait when the disk (or the denoiser) is the slower one.
The first error raised by a job is raised again in the rendering thread, at
its next :meth:`FrameWriter.submit` or at :meth:`FrameWriter.close`; no job
starts after it.

The rendering thread waits for the queue in short steps, never in one
blocking wait: after a Mitsuba render Python's SIGINT handler is installed
with ``SA_RESTART`` (Mitsuba restores it so), and a blocking lock wait then
does not wake on Ctrl-C until the lock is free, seconds later. A Ctrl-C
while :meth:`FrameWriter.close` waits lets the jobs being run finish (no
half-written file is left), drops those not started, and is raised then (a
second one stops the wait).
"""

from __future__ import annotations

import os
import queue
import threading
from collections.abc import Callable

__all__ = ["FrameWriter", "default_workers"]


#: Memory the frames held by a writer (queued and being written) may take.
HELD_BYTES = 1 << 30
#: Seconds between two looks at Ctrl-C while the rendering thread waits.
_POLL_SECONDS = 0.1


def default_workers(frame_bytes: int = 0) -> int:
    """Writer threads for frames of ``frame_bytes`` each: up to 4, leaving a
    core to the renderer's own Python thread, and few enough that the frames
    held (two per worker) stay within :data:`HELD_BYTES`. The cores are
    those this process may run on (a batch job or ``taskset`` may allow a
    few of the machine's)."""
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    workers = max(1, min(4, (cores or 1) - 1))
    return max(1, min(workers, HELD_BYTES // max(1, 2 * frame_bytes)))


class FrameWriter:
    """Runs jobs (callables) in ``workers`` background threads (one: in the
    order submitted), with at most ``depth`` jobs waiting (default: one per
    worker, and at least 2)."""

    def __init__(self, depth: int | None = None, workers: int = 1) -> None:
        if workers < 1:
            raise ValueError(f"FrameWriter needs at least one worker, got {workers}")
        self._jobs: queue.Queue[Callable[[], None] | None] = queue.Queue(maxsize=depth or max(2, workers))
        self._error: BaseException | None = None
        self._dropping = False  # set on Ctrl-C in close(): run no more jobs
        self._threads = [threading.Thread(target=self._run, name=f"lathe-frame-writer-{k}", daemon=True)
                         for k in range(workers)]
        self._stopped = [threading.Event() for _ in self._threads]  # (not join: see _wait)
        for thread in self._threads:
            thread.start()

    def _run(self) -> None:
        stopped = self._stopped[self._threads.index(threading.current_thread())]
        try:
            while (job := self._jobs.get()) is not None:
                if self._error is None and not self._dropping:  # after a failure, drain without running
                    try:
                        job()
                    except BaseException as e:  # handed to the rendering thread
                        self._error = e
        finally:
            stopped.set()

    def _raise(self) -> None:
        if self._error is not None:
            error, self._error = self._error, None
            raise error

    def submit(self, job: Callable[[], None]) -> None:
        """Queue ``job`` (waits while ``depth`` jobs are queued); raises the
        error of an earlier job, if any."""
        self._raise()
        self._put(job)

    def _put(self, job: Callable[[], None] | None) -> None:
        """Queue ``job`` (None: a stop mark), waiting in short steps."""
        while True:
            try:
                return self._jobs.put(job, timeout=_POLL_SECONDS)
            except queue.Full:
                pass

    def _wait(self) -> None:
        """Wait in short steps until every thread has stopped (an
        interrupted ``Thread.join`` marks a running thread stopped)."""
        for thread, stopped in zip(self._threads, self._stopped, strict=True):
            while not stopped.wait(_POLL_SECONDS):
                pass
            thread.join()  # (at once: the thread is returning)

    def close(self) -> None:
        """Finish the queued jobs and stop the threads; raises the error of a
        job, if any. On Ctrl-C meanwhile, waits only for the jobs running,
        then raises KeyboardInterrupt (at once on a second Ctrl-C: a write
        that hangs, on a network disk say, must not hold the command)."""
        stop_marks = sum(not stopped.is_set() for stopped in self._stopped)
        interrupt: KeyboardInterrupt | None = None
        while True:
            try:
                while stop_marks:
                    self._put(None)  # one stop mark per thread
                    stop_marks -= 1
                self._wait()
                break
            except KeyboardInterrupt as e:
                if interrupt is not None:  # a second Ctrl-C: a write hangs, stop waiting
                    raise
                interrupt, self._dropping = e, True
        if interrupt is not None:
            raise interrupt
        self._raise()

    def __enter__(self) -> FrameWriter:
        return self

    def __exit__(self, exc_type: object, exc: object, traceback: object) -> None:
        if exc_type is None:
            self.close()
            return
        try:  # the error already on its way matters more than a writer's
            self.close()
        except Exception:
            pass
