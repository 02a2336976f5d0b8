"""Root finding for the B-spline kernel (kernels/bspline.py, whose
docstring describes the method): polynomial helpers unrolled per degree and
vectorized over lanes, bracketed safeguarded Newton searches and the
isolation of critical points, down the derivative chain."""

from __future__ import annotations

from collections.abc import Callable

import drjit as dr
import mitsuba as mi

from .bspline_data import (
    _STEPS_CRIT,
    _T_FINAL,
    _T_RESOLUTION,
)
from .common import (
    LatheData,
)

# ---------------------------------------------------------------------------
# Polynomial helpers (unrolled per degree, vectorized over lanes)
# ---------------------------------------------------------------------------

def _squared(data: LatheData):
    """Whether the ``R`` slots of ``data`` hold ``R^2`` (the sor kind, eq.
    20): the Python bool of one lathe's own :class:`BSplineData`, so that
    its kernel is specialised to one form; else (a view of several profiles'
    data, kernels/top_level.py, which has no such bool) a per-lane mask
    from the profile's ``r_squared_flag``."""
    flag = getattr(data, "r_squared", None)
    return flag if isinstance(flag, bool) else data.r_squared_flag != 0


def _by_form(squared, of_square: Callable, of_radius: Callable, *args):
    """``of_square(*args)`` where ``squared`` (see :func:`_squared`), else
    ``of_radius(*args)``: only the one needed for a Python bool, both
    selected per lane for a mask. The callables return a value or a
    tuple/list."""
    if isinstance(squared, bool):
        return of_square(*args) if squared else of_radius(*args)
    a, b = of_square(*args), of_radius(*args)
    if isinstance(a, (list, tuple)):
        return type(a)(dr.select(squared, x, y) for x, y in zip(a, b, strict=True))
    return dr.select(squared, a, b)


def _polyval(c: list, x):
    """Horner evaluation of ascending coefficients ``c`` at ``x``."""
    v = c[-1]
    for ck in reversed(c[:-1]):
        v = dr.fma(v, x, ck)
    return v


def _polyval_d(c: list, x):
    """Value and first derivative of ascending coefficients ``c`` at ``x``."""
    v, dv = c[-1], mi.Float(0)
    for ck in reversed(c[:-1]):
        dv = dr.fma(dv, x, v)
        v = dr.fma(v, x, ck)
    return v, dv


def _polyder(c: list) -> list:
    return [c[k] * float(k) for k in range(1, len(c))]


def _polymul(p: list, q: list) -> list:
    out = [None] * (len(p) + len(q) - 1)
    for i, pi in enumerate(p):
        for j, qj in enumerate(q):
            out[i + j] = pi * qj if out[i + j] is None else dr.fma(pi, qj, out[i + j])
    return out


def _bracket_root(c: list, dc: list, x0, x1, f0, f1, steps: int):
    """Root of the polynomial ``c`` (derivative ``dc``) on [x0, x1], where it
    is monotonic; ``f0``, ``f1`` are its values at the ends.

    Returns ``(x, found)``. ``found``: ``f0`` and ``f1`` differ in sign (or
    one is 0), so exactly one root lies in the bracket. It is refined by
    safeguarded Newton steps (as ``rtsafe`` in Numerical Recipes), starting
    from the false-position point: a step that would leave the bracket, or
    that did not halve the previous one, is replaced by bisection, so the
    bracket shrinks at least geometrically; the result is the evaluated
    point with the least ``|f|`` (always inside the bracket). A symbolic
    loop of at most ``steps`` iterations ends when every lane of a packet
    has converged (usually after 2-4 steps on a leaf). Without a sign change
    ``x`` is ``x1`` (this keeps the list of critical points sorted for the
    next level).
    """
    return _bracket_roots(c, dc, [(x0, x1, f0, f1, None)], steps)[0]


def _bracket_roots(c: list, dc: list, brackets: list, steps: int, strict: bool = False) -> list:
    """:func:`_bracket_root` on several brackets ``(x0, x1, f0, f1, mask)``
    of one polynomial at once (``mask``: lanes that search it, ``None``:
    all), in one symbolic loop: every bracket takes the same steps as on its
    own (a converged bracket's point stays put), so the results are the
    same, and a kernel holds one loop instead of one per bracket (fewer
    loops make faster LLVM code, even where they seldom run).

    ``strict``: a root is found exactly where ``f0 < 0`` and ``f1 < 0``
    differ (0 counts as positive), so that along a chain of brackets the
    found roots change the sign as often as the ends do (the parity rule of
    :func:`_take_interval`); else also where ``f0`` or ``f1`` is 0."""
    state, starts = [], []
    for x0, x1, f0, f1, mask in brackets:
        if strict:
            found = (f0 < 0) != (f1 < 0)
        else:
            found = ((f0 <= 0) & (f1 >= 0)) | ((f0 >= 0) & (f1 <= 0))
        if mask is not None:
            found &= mask
        a, b = mi.Float(x0), mi.Float(x1)  # bracket [a, b]; f(a) has the sign of f0
        x = dr.clip(x0 - f0 * (x1 - x0) / (f1 - f0), a, b)  # current estimate
        x = dr.select(dr.isfinite(x), x, 0.5 * (a + b))
        # (a, b, x, step before last, last step, converged or nothing to
        # find, evaluated point with the least |f|, its |f|)
        state.append((a, b, x, b - a, b - a, ~found, mi.Float(x), mi.Float(dr.inf)))
        starts.append((found, f0 < 0))

    def pending(k, state):
        todo = ~state[0][5]
        for bracket in state[1:]:
            todo |= ~bracket[5]
        return todo & (k < steps)

    def step(k, state):
        return k + 1, [_newton_step(c, dc, bracket, neg0)
                       for bracket, (_, neg0) in zip(state, starts, strict=True)]

    _, state = dr.while_loop((mi.UInt32(0), state), pending, step)
    out = []
    for (x0, x1, f0, f1, _), (found, _), bracket in zip(brackets, starts, state, strict=True):
        x = dr.select(f0 == 0, x0, dr.select(f1 == 0, x1, bracket[6]))
        out.append((dr.select(found, x, x1), found))
    return out


def _newton_step(c: list, dc: list, bracket: tuple, neg0) -> tuple:
    """One safeguarded Newton step of :func:`_bracket_roots` on one bracket
    state (the order of its fields is documented there)."""
    a, b, x, dx_old, dx, done, best_x, best_f = bracket
    f, df = _polyval_d(c, x)
    # Near the root f is float32 noise, and the steps below may then
    # bisect away from it; the least |f| seen is the answer.
    better = dr.abs(f) < best_f
    best_x = dr.select(better, x, best_x)
    best_f = dr.select(better, dr.abs(f), best_f)
    left = (f < 0) == neg0
    a = dr.select(left, x, a)
    b = dr.select(left, b, x)
    # Converged: an exact zero, or a Newton step below float32 resolution of
    # t (checked first: the test below would then pick bisection and jump
    # away from the root).
    done = done | (f == 0) | (dr.abs(f) <= _T_RESOLUTION * dr.abs(df))
    # Newton unless it leaves [a, b] or converges slower than bisection.
    xn = x - f / df
    newton = (df != 0) & (xn >= a) & (xn <= b) & (dr.abs(2.0 * f) <= dr.abs(dx_old * df))
    x_new = dr.select(newton, xn, 0.5 * (a + b))
    # A Newton step below _T_FINAL is the last one: the next would be of
    # its square's order, below float32 resolution (saves an evaluation).
    last = ~done & newton & (dr.abs(f) <= _T_FINAL * dr.abs(df))
    best_x = dr.select(last, xn, best_x)
    return a, b, dr.select(done, x, x_new), dx, x_new - x, done | last, best_x, best_f


def _isolate_critical(derivs: list, lo, hi) -> list:
    """Sorted critical points of ``derivs[0]`` (degree k) on [lo, hi]: the
    roots of its derivative, found level by level from the linear
    ``derivs[-1]`` up. ``derivs[j]`` is the j-th derivative of ``derivs[0]``.
    Missing points are filled with interval ends (harmless: they only split a
    monotonic interval). Returns k - 1 values.

    One symbolic loop runs the levels: each level's polynomial is padded
    with zero coefficients to the degree of the last (which changes no
    value), its brackets likewise with empty ones at ``hi``, so that one
    search of k - 1 brackets serves all levels: a much shorter kernel than
    a search per level (this runs seldom, but its code slows the rest)."""
    # The root of the linear derivs[-1] is the critical point of derivs[-2].
    lin = derivs[-1]
    x = dr.select(lin[1] != 0, -lin[0] / lin[1], hi)
    x = dr.select(dr.isfinite(x), x, hi)
    width = len(derivs[1])  # coefficients of the last level's polynomial

    def padded(c: list) -> list:
        return list(c) + [mi.Float(0.0)] * (width - len(c))

    levels = {j: (padded(derivs[j]), padded(derivs[j + 1])) for j in range(1, len(derivs) - 1)}

    def level_poly(j):
        """The polynomial of level ``j`` and its derivative (padded)."""
        c, dc = levels[len(derivs) - 2]
        for level in range(len(derivs) - 3, 0, -1):
            c = [dr.select(j == level, p, q) for p, q in zip(levels[level][0], c, strict=True)]
            dc = [dr.select(j == level, p, q) for p, q in zip(levels[level][1], dc, strict=True)]
        return c, dc

    def step(j, crit):
        # Level j turns its critical points into its roots, the critical
        # points of level j - 1.
        c, dc = level_poly(j)
        xs = [lo] + crit[:width - 2] + [hi]
        fs = [_polyval(c, xk) for xk in xs]
        brackets = [(xs[k], xs[k + 1], fs[k], fs[k + 1], None) for k in range(len(xs) - 1)]
        return j - 1, [r for r, _ in _bracket_roots(c, dc, brackets, _STEPS_CRIT)]

    crit = [dr.clip(x, lo, hi)] + [mi.Float(hi) for _ in range(width - 2)]
    _, crit = dr.while_loop((mi.UInt32(len(derivs) - 2), crit), lambda j, crit: j > 0, step)
    return crit
