"""lathe_shape: exact rendering of transparent solids of revolution in Mitsuba 3.

Importing the package registers its Mitsuba plugins for the active variant
(select it first; one JIT variant per process: after a later
``mi.set_variant`` to another JIT variant the plugins refuse to load,
naming the variant they were imported under):

* ``<shape type="lathe">`` -- a solid of revolution; stock integrators render
  its reference tessellation, ``lathe_path`` renders it exactly;
* ``<integrator type="lathe_path">`` -- a path tracer that intersects every
  lathe exactly.

Call :func:`register` by hand only if plugins were cleared.
"""

from __future__ import annotations

# ``_signal``, the C half of ``signal``: a built-in module, imported without
# running any Python code. (``import signal`` builds its enums first, about
# half a millisecond in which a Ctrl-C still had Python's default effect: a
# KeyboardInterrupt traceback from this file, seen on a 16-core machine.)
import _signal
import os as _os
import sys as _sys


def _command_name() -> str | None:
    """``lathe-render`` etc. when this process is one of the package's
    commands (a console script, or ``python -m lathe_shape.cli.NAME``)."""
    commands = ("render", "turntable", "compare", "profile", "sweep")
    if _sys.argv and _os.path.basename(_sys.argv[0]) in {f"lathe-{c}" for c in commands}:
        return _os.path.basename(_sys.argv[0])
    argv = getattr(_sys, "orig_argv", [])
    for flag, module in zip(argv, argv[1:], strict=False):
        if flag == "-m" and module in {f"lathe_shape.cli.{c}" for c in commands}:
            return "lathe-" + module.rsplit(".", 1)[1]
    return None


if _command_name() and _signal.getsignal(_signal.SIGINT) in (_signal.default_int_handler, _signal.SIG_IGN):
    # A command process: a watcher thread owns Ctrl-C from here on, also
    # while Mitsuba and Dr.Jit still import and while a render runs (their
    # threads inherit the blocked SIGINT; see cli/interrupts.py). Also when
    # started with SIGINT ignored (``cmd &`` in a script): Mitsuba's render
    # would install its own handler over SIG_IGN anyway. (Blocked before
    # the watcher's module imports: a Ctrl-C meanwhile waits for it.)
    _signal.pthread_sigmask(_signal.SIG_BLOCK, {_signal.SIGINT})
    from .cli import interrupts as _interrupts

    _interrupts.install(_command_name())

import mitsuba as mi  # noqa: E402 (after the Ctrl-C watcher)

from .plugin import on_variant_change, register  # noqa: E402
from .plugin.variants import MIN_LLVM_VERSION, check_llvm  # noqa: E402
from .profiles import Profile, ProfileError, make_profile  # noqa: E402

__all__ = [
    "MIN_LLVM_VERSION",
    "Profile",
    "ProfileError",
    "check_llvm",
    "make_profile",
    "register",
]

__version__ = "0.1.0"

#: Python's recursion limit while the package is loaded (at least). Mitsuba
#: loads a scene's shapes in parallel on Dr.Jit's worker threads, and a
#: ``lathe`` constructor waiting there on an evaluation (its mesh's bounding
#: box) runs the next queued constructor on the same thread: constructors
#: nest, a few Python frames each. Under the default limit of 1000 a few
#: hundred lathes (fewer under a deep caller such as a test runner) ended
#: in a RecursionError. A constructor nested in another now only queues
#: its mesh, which the outermost writes (nesting at most 2 deep: 10,000
#: lathes load in parallel, docs/limits.md); this limit stays as a margin
#: for other Python plugins nesting there. The package's own loading is
#: sequential (tools/scenes.py) and never nests.
RECURSION_LIMIT = 4_000
if _sys.getrecursionlimit() < RECURSION_LIMIT:
    _sys.setrecursionlimit(RECURSION_LIMIT)

mi.detail.add_variant_callback(on_variant_change)
register()
