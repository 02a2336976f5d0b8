"""The literal ``lathe { ... }`` and ``sor { ... }`` blocks of a POV-Ray
scene file, as profiles (numpy only).

Recognised in a block: the spline type (``linear_spline``,
``quadratic_spline``, ``cubic_spline``, ``bezier_spline``; lathes only,
default linear), the point count, the points ``<r, h>`` (literal numbers),
``open`` (sor), ``sturm`` (noted: the exact kernel needs no Sturm
sequences) and the literal transforms ``scale``, ``rotate`` and ``translate``
(composed in order, as POV-Ray does). Any other statement (``pigment``,
``texture``, ``matrix``, ...) is skipped with a note. ``#declare NAME =`` (or
``#local``) before a block names it. A block that cannot be read (a missing
count or brace, fewer points than announced, an expression where a number
must be) raises :class:`PovError` naming the file and line.

Kinds: ``linear_spline`` is a ``polyline``, ``quadratic_spline`` a
``quadratic``, ``cubic_spline`` a ``catmull_rom``, ``bezier_spline`` a
``bezier`` profile, and a ``sor`` a ``sor``. A lathe whose curve neither
closes nor has both ends on the axis is an open sheet (POV-Ray renders any
lathe as a surface); a sor is open exactly when it says ``open``.

Axes. POV-Ray is left-handed with +y up, and revolves a lathe's points
``<r, h>`` about its y axis: ``(r cos a, h, r sin a)``. Mitsuba scenes of this
project are right-handed with +z up. Swapping y and z, ``(x, y, z)_Mitsuba =
(x, z, y)_POV``, maps one to the other without mirroring the picture (a
camera converted alike sees the same image), and maps a POV-Ray lathe's
object space onto the ``lathe`` plugin's local frame (axis +z, points ``(r
cos a, r sin a, h)``). So a block with POV-Ray transform ``M`` becomes a
``lathe`` with ``to_world = S M S`` (``S`` the y/z swap, its own inverse);
:func:`to_world` gives it.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass, field

import numpy as np

from .bspline import evaluate
from .errors import ProfileError
from .spline_kinds import curve_form, kind_coefficients, to_bspline_controls

__all__ = ["PovError", "PovBlock", "SPLINE_KINDS", "read_pov_blocks", "to_world", "is_open",
           "lathe_snippet"]


class PovError(ProfileError):
    """A POV-Ray block that cannot be read; the message names file and line."""


#: POV-Ray spline keywords and the profile kinds they become.
SPLINE_KINDS = {"linear_spline": "polyline", "quadratic_spline": "quadratic",
                "cubic_spline": "catmull_rom", "bezier_spline": "bezier"}

#: Tokens: comments, strings, numbers, words (with #directives), symbols.
_TOKEN = re.compile(r"""(?P<comment>//[^\n]*|/\*.*?\*/)|(?P<string>"(?:[^"\\\n]|\\.)*")
    |(?P<number>(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?)|(?P<word>\#?[A-Za-z_][A-Za-z0-9_]*)
    |(?P<space>\s+)|(?P<symbol>.)""", re.VERBOSE | re.DOTALL)

#: The y/z swap between POV-Ray's and Mitsuba's axes (module docstring).
_SWAP = np.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0], [0, 1.0, 0, 0], [0, 0, 0, 1.0]])


@dataclass
class PovBlock:
    """One ``lathe`` or ``sor`` block."""

    #: The declared name, else ``<file stem>_<object><index>``.
    name: str
    #: ``lathe`` or ``sor``.
    object: str
    #: The profile kind (``polyline``, ``quadratic``, ``catmull_rom``, ``bezier``, ``sor``).
    kind: str
    #: (n, 2) points (r, h).
    points: np.ndarray
    #: POV-Ray's ``open`` (sor), or a lathe curve that does not close.
    open_sheet: bool
    sturm: bool
    #: 4x4 POV-Ray object-to-world transform of the literal transforms.
    transform: np.ndarray
    #: ``file:line`` of the block's keyword.
    where: str
    #: Statements that were skipped, and other remarks.
    notes: list[str] = field(default_factory=list)


class _Tokens:
    """(kind, text, line) tokens of a POV-Ray file, comments dropped."""

    def __init__(self, text: str, path: str) -> None:
        self.path, self.items, line = path, [], 1
        for m in _TOKEN.finditer(text):
            kind = m.lastgroup
            if kind not in ("comment", "space"):
                self.items.append((kind, m.group(), line))
            line += m.group().count("\n")
        self.pos, self.last_line = 0, line

    def peek(self, ahead: int = 0) -> tuple[str, str, int]:
        k = self.pos + ahead
        return self.items[k] if k < len(self.items) else ("end", "", self.last_line)

    def take(self) -> tuple[str, str, int]:
        token = self.peek()
        self.pos += 1
        return token

    def error(self, message: str, line: int | None = None) -> PovError:
        return PovError(f"{self.path}:{line if line is not None else self.peek()[2]}: {message}")

    def expect(self, text: str, what: str) -> None:
        kind, got, line = self.take()
        if got != text:
            raise self.error(f"expected '{text}' {what}, got {got or 'the end of the file'!r}", line)

    def number(self, what: str) -> float:
        """A literal number, with an optional sign."""
        sign = 1.0
        while self.peek()[1] in "+-" and self.peek()[0] == "symbol":
            sign *= -1.0 if self.take()[1] == "-" else 1.0
        kind, text, line = self.take()
        if kind != "number":
            raise self.error(f"expected a literal number for {what}, got {text or 'the end'!r} "
                             f"(expressions and identifiers are not evaluated)", line)
        if self.peek()[0] == "symbol" and self.peek()[1] in "*/+-" and self.peek(1)[0] in ("number", "word"):
            raise self.error(f"{what}: expressions are not evaluated; write a literal number", line)
        return sign * float(text)

    def vector(self, size: int, what: str) -> np.ndarray:
        """``<a, b[, c]>`` with ``size`` literal numbers."""
        self.expect("<", f"to open {what}")
        values = [self.number(what)]
        while self.peek()[1] == ",":
            self.take()
            values.append(self.number(what))
        line = self.peek()[2]
        self.expect(">", f"to close {what}")
        if len(values) != size:
            raise self.error(f"{what} has {len(values)} components, expected {size}", line)
        return np.array(values)


def read_pov_blocks(path: str | os.PathLike) -> list[PovBlock]:
    """Every literal ``lathe`` and ``sor`` block of a POV-Ray file, in file
    order (see the module docstring). Raises :class:`PovError`."""
    path = os.fspath(path)
    try:
        with open(path, encoding="utf-8", errors="replace") as f:
            tokens = _Tokens(f.read(), path)
    except OSError as e:
        raise PovError(f"{path}: cannot read POV-Ray file ({e.strerror})") from None
    stem = os.path.splitext(os.path.basename(path))[0]
    blocks: list[PovBlock] = []
    while tokens.peek()[0] != "end":
        kind, text, line = tokens.take()
        if kind == "word" and text in ("lathe", "sor") and tokens.peek()[1] == "{":
            name = _declared_name(tokens.items, tokens.pos - 1)
            name = name or f"{stem}_{text}{sum(b.object == text for b in blocks) + 1}"
            blocks.append(_read_block(tokens, text, name, f"{path}:{line}"))
    return blocks


def _declared_name(items: list, k: int) -> str | None:
    """``NAME`` of ``#declare NAME =`` (or ``#local``) right before token ``k``."""
    if k >= 3 and items[k - 1][1] == "=" and items[k - 3][1] in ("#declare", "#local"):
        return items[k - 2][1]
    return None


def _read_block(tokens: _Tokens, obj: str, name: str, where: str) -> PovBlock:
    tokens.expect("{", f"after '{obj}'")
    kind = "sor"
    if obj == "lathe":
        kind = "polyline"
        if tokens.peek()[1] in SPLINE_KINDS:
            kind = SPLINE_KINDS[tokens.take()[1]]
        elif tokens.peek()[0] == "word":
            raise tokens.error(f"unknown lathe spline type '{tokens.peek()[1]}' (expected one of: "
                               f"{', '.join(SPLINE_KINDS)}, or the literal point count)")
    count_line = tokens.peek()[2]
    count = tokens.number(f"the point count of the {obj}")
    if count != int(count) or count < 2:
        raise tokens.error(f"the point count of the {obj} must be a whole number >= 2, got {count:g}",
                           count_line)
    points = []
    for k in range(int(count)):
        if tokens.peek()[1] == ",":
            tokens.take()
        if tokens.peek()[1] != "<":
            raise tokens.error(f"the {obj} announces {int(count)} points but point {k + 1} is missing "
                               f"(got {tokens.peek()[1] or 'the end of the file'!r})")
        points.append(tokens.vector(2, f"point {k + 1} of the {obj}"))
    block = PovBlock(name=name, object=obj, kind=kind, points=np.array(points), open_sheet=False,
                     sturm=False, transform=np.eye(4), where=where)
    _read_modifiers(tokens, block)
    if obj == "lathe":
        block.open_sheet = is_open(kind, block.points, where)
        if block.open_sheet:
            block.notes.append("the curve does not close (nor has both ends on the axis): "
                               "written as an open sheet")
    return block


def _read_modifiers(tokens: _Tokens, block: PovBlock) -> None:
    """Everything after the points up to the block's closing brace."""
    skipped: dict[str, int] = {}
    while True:
        kind, text, line = tokens.take()
        if kind == "end":
            raise tokens.error(f"the {block.object} block opened at {block.where} is not closed "
                               f"(missing '}}')", line)
        if text == "}":
            break
        if text == "open":
            if block.object != "sor":
                raise tokens.error("'open' is a sor modifier (a lathe is open when its curve is)", line)
            block.open_sheet = True
        elif text == "sturm":
            block.sturm = True
            block.notes.append("sturm: not needed (the exact kernel brackets every root)")
        elif text in ("scale", "translate", "rotate"):
            step = _transform(tokens, text)
            block.transform = step @ block.transform
            if text == "scale" and _singular(block.transform):
                raise tokens.error(f"scale {_fmt_scale(step)}: the {block.object}'s "
                                   f"transform becomes singular (a zero or vanishing scale "
                                   f"component flattens the shape; Mitsuba cannot load it)", line)
        elif text == ",":
            continue
        else:
            skipped.setdefault(text, line)
            _skip_statement(tokens)
    block.notes += [f"line {line}: '{word}' ignored" for word, line in skipped.items()]


def _skip_statement(tokens: _Tokens) -> None:
    """Skip one statement's arguments: a braced body, or values up to the
    next word or brace."""
    if tokens.peek()[1] == "{":
        depth = 0
        while True:
            kind, text, line = tokens.take()
            if kind == "end":
                raise tokens.error("unbalanced braces", line)
            depth += {"{": 1, "}": -1}.get(text, 0)
            if depth == 0:
                return
    while tokens.peek()[0] in ("number", "symbol", "string") and tokens.peek()[1] not in "{}":
        tokens.take()


def _singular(m: np.ndarray) -> bool:
    """Whether the linear part of ``m`` is singular or too nearly so for a
    lathe's ``to_world``: the test of ``plugin.params.check_transform``
    (determinant relative to the product of the column lengths), so that
    what is written here loads."""
    linear = m[:3, :3]
    if not np.isfinite(linear).all():
        return True
    return abs(np.linalg.det(linear)) <= 1e-9 * float(np.prod(np.linalg.norm(linear, axis=0)))


def _fmt_scale(m: np.ndarray) -> str:
    """The factors of the scale matrix ``m``, ``<x, y, z>``."""
    return "<" + ", ".join(f"{v:g}" for v in np.diag(m)[:3]) + ">"


def _transform(tokens: _Tokens, op: str) -> np.ndarray:
    """The 4x4 matrix of a literal ``scale``, ``translate`` or ``rotate``."""
    if op == "scale" and tokens.peek()[1] != "<":
        v = np.full(3, tokens.number("scale"))
    else:
        v = tokens.vector(3, op)
    m = np.eye(4)
    if op == "scale":
        m[:3, :3] = np.diag(v)
    elif op == "translate":
        m[:3, 3] = v
    else:  # about x, then y, then z, in degrees
        for axis, angle in enumerate(np.radians(v)):
            c, s = math.cos(angle), math.sin(angle)
            i, j = [(1, 2), (2, 0), (0, 1)][axis]
            r = np.eye(4)
            r[i, i], r[i, j], r[j, i], r[j, j] = c, -s, s, c
            m = r @ m
    return m


def is_open(kind: str, points: np.ndarray, where: str) -> bool:
    """Whether a lathe curve of ``kind`` neither closes nor has both ends on
    the axis (then it can only be an open sheet)."""
    p = np.asarray(points, dtype=np.float64)
    if kind == "polyline":
        start, end = p[0], p[-1]
    else:
        seg = to_bspline_controls(kind_coefficients(kind, p, where))
        start = np.array(evaluate(seg, 0, 0.0), dtype=np.float64)
        end = np.array(evaluate(seg, len(seg) - 1, 1.0), dtype=np.float64)
    scale = float(np.ptp(p, axis=0).max()) or 1.0
    loop, on_axis = curve_form(start, end, scale)
    return not (loop or on_axis)


def to_world(transform: np.ndarray) -> np.ndarray:
    """The ``lathe`` plugin's ``to_world`` for a POV-Ray object transform
    (module docstring: ``S M S``)."""
    return _SWAP @ np.asarray(transform, dtype=np.float64) @ _SWAP


def lathe_snippet(block: PovBlock, filename: str) -> str:
    """A Mitsuba ``<shape type="lathe">`` element for ``block``, whose
    profile CSV is ``filename`` (relative to the scene file)."""
    matrix = " ".join(f"{v:.9g}" for v in to_world(block.transform).ravel())
    return (f"<!-- POV-Ray {block.object} '{block.name}' of {block.where}; POV-Ray (x, y, z) is "
            f"Mitsuba (x, z, y) (left-handed y-up to right-handed z-up). Add a <bsdf>. -->\n"
            f'<shape type="lathe" id="{block.name}">\n'
            f'    <string name="filename" value="{filename}"/>\n'
            f'    <string name="kind" value="{block.kind}"/>\n'
            f'    <boolean name="open" value="{str(block.open_sheet).lower()}"/>\n'
            f'    <transform name="to_world">\n'
            f'        <matrix value="{matrix}"/>\n'
            f"    </transform>\n"
            f"</shape>\n")
