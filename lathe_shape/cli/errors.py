"""The commands' errors: :class:`CliError` (a user error, reported as
``PROG: error: MESSAGE`` with status 2) and how any exception becomes that
one-line message (:func:`error_message`), Ctrl-C included
(:func:`is_interrupt`)."""

from __future__ import annotations

__all__ = ["CliError", "error_message", "is_interrupt", "root_message"]


class CliError(Exception):
    """A user error: :func:`run_command` prints ``PROG: error: MESSAGE`` and
    exits with status 2, without a traceback."""


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
