"""A background thread that finishes frames (denoise, EXR and PNG writes)
while the next frame renders, so a turntable runs at the speed of the render
itself.

At most ``depth`` frames wait in the queue, which bounds the memory held and
makes the renderer wait when the disk (or the denoiser) is the slower one.
The first error raised by a job is raised again in the rendering thread, at
its next :meth:`FrameWriter.submit` or at :meth:`FrameWriter.close`.
"""

from __future__ import annotations

import queue
import threading
from collections.abc import Callable

__all__ = ["FrameWriter"]


class FrameWriter:
    """Runs jobs (callables) one after another in a background thread."""

    def __init__(self, depth: int = 2) -> None:
        self._jobs: queue.Queue[Callable[[], None] | None] = queue.Queue(maxsize=depth)
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._run, name="lathe-frame-writer", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while True:
            job = self._jobs.get()
            try:
                if job is None:
                    return
                if self._error is None:  # after a failure, drain without running
                    job()
            except BaseException as e:  # handed to the rendering thread
                self._error = e
            finally:
                self._jobs.task_done()

    def _raise(self) -> None:
        if self._error is not None:
            error, self._error = self._error, None
            raise error

    def submit(self, job: Callable[[], None]) -> None:
        """Queue ``job`` (waits while ``depth`` jobs are queued); raises the
        error of an earlier job, if any."""
        self._raise()
        self._jobs.put(job)

    def close(self) -> None:
        """Finish the queued jobs and stop the thread; raises the error of a
        job, if any."""
        if self._thread.is_alive():
            self._jobs.put(None)
            self._thread.join()
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
