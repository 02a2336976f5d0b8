"""Float, vector, colour and string expressions of POV-Ray SDL, evaluated
while read from an :class:`~.interpreter.Interpreter`.

Operators: ``? :``, ``|``, ``&``, ``< <= = != >= >`` (inside parentheses
only, as in POV-Ray, where ``<`` and ``>`` also bracket vectors), ``+ -``,
``* /``, unary ``- + !``; vectors ``<a, b, ...>`` (2 to 5 components; a
number meets a vector as that vector's size, a shorter vector is padded
with zeros); members ``.x .y .z .t .u .v .red .green .blue .filter
.transmit .gray``; array elements ``A[i]``; colours ``rgb``, ``rgbf``,
``rgbt``, ``rgbft`` (and ``srgb...``, linearised), ``color``/``colour``.
Constants ``pi tau x y z t u v true false yes no on off clock
frame_number version ...``; functions in :data:`FUNCTIONS` plus ``seed``,
``rand`` (a fixed generator: not POV-Ray's sequence), ``defined``,
``dimension_size``, ``min_extent``/``max_extent`` (lathes and sors only),
``trace``/``inside`` (not evaluated: a zero vector or 0, with a note).
"""

from __future__ import annotations

import math

import numpy as np

from .tokens import PovError, Token
from .values import Macro, PovArray, rotate_matrix, type_name

__all__ = ["parse_expression", "parse_condition", "parse_value", "truth", "as_float", "as_vector",
           "builtin_constants", "set_element", "FUNCTIONS"]


def builtin_constants() -> dict:
    """POV-Ray's predefined identifiers (single-frame render, clock 0)."""
    vec = lambda *v: np.array(v, dtype=np.float64)  # noqa: E731
    return {"pi": math.pi, "tau": 2 * math.pi, "x": vec(1, 0, 0), "y": vec(0, 1, 0),
            "z": vec(0, 0, 1), "t": vec(0, 0, 0, 1), "u": vec(1, 0), "v": vec(0, 1),
            "true": 1.0, "yes": 1.0, "on": 1.0, "false": 0.0, "no": 0.0, "off": 0.0,
            "clock": 0.0, "clock_delta": 1.0, "clock_on": 0.0, "frame_number": 0.0,
            "initial_frame": 1.0, "final_frame": 1.0, "initial_clock": 0.0, "final_clock": 1.0,
            "image_width": 320.0, "image_height": 240.0, "version": 3.7, "now": 0.0,
            "input_file_name": "scene.pov"}


def _fmt(v) -> str:
    return f"{v:g}" if isinstance(v, float) else str(v)


def truth(value, token: Token) -> bool:
    if isinstance(value, float):
        return abs(value) > 1e-10
    if isinstance(value, np.ndarray):
        return bool(np.any(np.abs(value) > 1e-10))
    raise PovError(f"{token.where}: a condition must be a number, got {type_name(value)}")


def as_float(value, token: Token, what: str) -> float:
    if isinstance(value, float):
        return value
    raise PovError(f"{token.where}: {what} must be a number, got {type_name(value)}")


def as_vector(value, size: int, token: Token, what: str) -> np.ndarray:
    """A number promoted to ``size`` components, or a vector of that size
    (a longer vector is refused, a shorter one padded with zeros)."""
    if isinstance(value, float):
        return np.full(size, value)
    if isinstance(value, np.ndarray):
        if len(value) > size and np.any(value[size:] != 0) and size < 3:
            raise PovError(f"{token.where}: {what} has {len(value)} components, expected {size}")
        return _pad(value, size)[:size]
    raise PovError(f"{token.where}: {what} must be a number or vector, got {type_name(value)}")


def _pad(v: np.ndarray, n: int) -> np.ndarray:
    return v if len(v) >= n else np.concatenate([v, np.zeros(n - len(v))])


def _arith(op: str, a, b, token: Token):
    if isinstance(a, str) or isinstance(b, str) or not isinstance(a, (float, np.ndarray)) \
            or not isinstance(b, (float, np.ndarray)):
        raise PovError(f"{token.where}: cannot apply '{op}' to {type_name(a)} and {type_name(b)}")
    if isinstance(a, np.ndarray) and isinstance(b, np.ndarray) and len(a) != len(b):
        n = max(len(a), len(b))
        a, b = _pad(a, n), _pad(b, n)
    with np.errstate(all="ignore"):
        if op == "+":
            return a + b
        if op == "-":
            return a - b
        if op == "*":
            return a * b
        if np.any(np.asarray(b) == 0):
            raise PovError(f"{token.where}: division by zero")
        return a / b


def _compare(op: str, a, b, token: Token) -> float:
    if isinstance(a, str) and isinstance(b, str):
        a, b = float((a > b) - (a < b)), 0.0
    if isinstance(a, np.ndarray) or isinstance(b, np.ndarray):
        if op in ("=", "!="):
            n = max(len(np.atleast_1d(a)), len(np.atleast_1d(b)))
            same = np.allclose(as_vector(a, n, token, "a comparison"), as_vector(b, n, token, "a comparison"))
            return float(same == (op == "="))
        raise PovError(f"{token.where}: '{op}' needs numbers, got vectors")
    a, b = as_float(a, token, "a comparison"), as_float(b, token, "a comparison")
    eps = 1e-10
    return float({"<": a < b, "<=": a <= b + eps, ">": a > b, ">=": a >= b - eps,
                  "=": abs(a - b) <= eps, "!=": abs(a - b) > eps}[op])


class _Parser:
    def __init__(self, interp, relational: bool) -> None:
        self.i = interp
        self.rel = [relational]

    def peek(self) -> Token:
        return self.i.peek_soft()

    def expression(self):
        if not self.rel[-1]:
            return self.additive()
        value = self.logical()
        if self.peek().text == "?":
            token = self.i.next()
            yes = self.expression()
            self.i.take(":", "in a ? : expression")
            no = self.expression()
            value = yes if truth(value, token) else no
        return value

    def logical(self):
        value = self.conjunction()
        while self.peek().text == "|" and self.peek().kind == "symbol":
            token = self.i.next()
            other = self.conjunction()
            value = float(truth(value, token) or truth(other, token))
        return value

    def conjunction(self):
        value = self.relation()
        while self.peek().text == "&" and self.peek().kind == "symbol":
            token = self.i.next()
            other = self.relation()
            value = float(truth(value, token) and truth(other, token))
        return value

    def relation(self):
        value = self.additive()
        while self.peek().kind == "symbol" and self.peek().text in ("<", "<=", "=", "!=", ">=", ">"):
            token = self.i.next()
            value = _compare(token.text, value, self.additive(), token)
        return value

    def additive(self):
        value = self.term()
        while self.peek().kind == "symbol" and self.peek().text in "+-":
            token = self.i.next()
            value = _arith(token.text, value, self.term(), token)
        return value

    def term(self):
        value = self.unary()
        while self.peek().kind == "symbol" and self.peek().text in "*/":
            token = self.i.next()
            value = _arith(token.text, value, self.unary(), token)
        return value

    def unary(self):
        token = self.peek()
        if token.kind == "symbol" and token.text in ("-", "+", "!"):
            self.i.next()
            value = self.unary()
            if token.text == "-":
                return _arith("*", -1.0, value, token)
            if token.text == "!":
                return float(not truth(value, token))
            return value
        return self.postfix()

    def postfix(self):
        value = self.primary()
        while True:
            token = self.peek()
            if token.kind == "symbol" and token.text == "." and isinstance(value, np.ndarray):
                self.i.next()
                value = _member(value, self.i.next())
            elif token.kind == "symbol" and token.text == "[" and isinstance(value, PovArray):
                self.i.next()
                index = int(as_float(self.nested(), token, "an array index"))
                self.i.take("]", "to close the array index")
                value = _element(value, index, token)
            else:
                return value

    def nested(self, relational: bool = True):
        self.rel.append(relational)
        try:
            return self.expression()
        finally:
            self.rel.pop()

    def primary(self):
        token = self.i.next()
        if token.kind == "number":
            return float(token.text)
        if token.kind == "string":
            return _unquote(token.text)
        if token.kind == "symbol" and token.text == "(":
            value = self.nested(True)
            self.i.take(")", "to close '('")
            return value
        if token.kind == "symbol" and token.text == "<":
            items = [self.nested(False)]
            while self.peek().text == ",":
                self.i.next()
                items.append(self.nested(False))
            self.i.take(">", "to close the vector")
            comps: list[float] = []
            for item in items:
                if isinstance(item, np.ndarray) and len(items) == 1:
                    comps.extend(item.tolist())
                else:
                    comps.append(as_float(item, token, "a vector component"))
            if not 2 <= len(comps) <= 5:
                raise PovError(f"{token.where}: a vector has 2 to 5 components, got {len(comps)}")
            return np.array(comps, dtype=np.float64)
        if token.kind == "word":
            return self.word(token)
        got = "the end of the file" if token.kind == "end" else repr(token.text)
        raise PovError(f"{token.where}: expected a number or vector, got {got}")

    def word(self, token: Token):
        name = token.text
        value = self.i.lookup(name)
        if value is not None and not isinstance(value, Macro):
            if isinstance(value, np.ndarray):
                return value.copy()
            return value
        if name in _COLOR_KEYWORDS:
            return self.color(token)
        if name in ("color", "colour"):
            nxt = self.peek()
            if nxt.kind == "word" and (nxt.text in _COLOR_KEYWORDS or nxt.text in _COMPONENTS):
                return self.color_components(np.zeros(5))
            return _to_color(self.additive_in(), token)
        if name in _COMPONENTS:  # color red 1 green 0.5 ...
            self.i.push(token)
            return self.color_components(np.zeros(5))
        if name in FUNCTIONS or name in _SPECIAL:
            return self.call(token)
        raise PovError(f"{token.where}: unknown identifier '{name}'")

    def additive_in(self):
        self.rel.append(False)
        try:
            return self.additive()
        finally:
            self.rel.pop()

    def color(self, token: Token):
        value = self.additive_in()
        size = {"rgb": 3, "rgbf": 4, "rgbt": 4, "rgbft": 5}[token.text.replace("srgb", "rgb")]
        v = as_vector(value, size, token, token.text)
        if token.text.startswith("srgb"):
            rgb = v[:3]
            v = v.copy()
            v[:3] = np.where(rgb <= 0.04045, rgb / 12.92, ((rgb + 0.055) / 1.055) ** 2.4)
        out = np.zeros(5)
        out[:3] = v[:3]
        if token.text.endswith("ft"):
            out[3:5] = v[3:5]
        elif token.text.endswith("f"):
            out[3] = v[3]
        elif token.text.endswith("t"):
            out[4] = v[3]
        return out

    def color_components(self, out: np.ndarray):
        while self.peek().kind == "word" and (self.peek().text in _COMPONENTS
                                              or self.peek().text in _COLOR_KEYWORDS):
            token = self.i.next()
            if token.text in _COLOR_KEYWORDS:
                out = self.color(token)
                continue
            value = as_float(self.additive_in(), token, token.text)
            out[_COMPONENTS[token.text]] = value
        return out

    def call(self, token: Token):
        name = token.text
        self.i.take("(", f"after {name}")
        if name == "defined":
            ident = self.i.next()
            self.i.take(")", "to close defined(")
            return float(self.i.defined(ident.text))
        args = []
        if self.peek().text != ")":
            while True:
                args.append(self.nested(True))
                if self.peek().text != ",":
                    break
                self.i.next()
        self.i.take(")", f"to close {name}(")
        if name in _SPECIAL:
            return _SPECIAL[name](self.i, args, token)
        fn, arity = FUNCTIONS[name]
        if arity is not None and len(args) not in arity:
            raise PovError(f"{token.where}: {name}() takes {' or '.join(map(str, arity))} arguments, "
                           f"got {len(args)}")
        try:
            with np.errstate(all="raise"):
                result = fn(*args)
        except (ValueError, ZeroDivisionError, FloatingPointError, OverflowError, TypeError) as e:
            raise PovError(f"{token.where}: {name}({', '.join(_fmt(a) for a in args)}): {e}") from None
        return float(result) if isinstance(result, (int, float, np.floating, bool)) else result


_COLOR_KEYWORDS = {"rgb", "rgbf", "rgbt", "rgbft", "srgb", "srgbf", "srgbt", "srgbft"}
_COMPONENTS = {"red": 0, "green": 1, "blue": 2, "filter": 3, "transmit": 4}


def _to_color(value, token: Token) -> np.ndarray:
    out = np.zeros(5)
    if isinstance(value, float):
        out[:3] = value
        return out
    if isinstance(value, np.ndarray):
        out[:min(5, len(value))] = value[:5]
        return out
    raise PovError(f"{token.where}: a colour must be a number or vector, got {type_name(value)}")


def _member(value: np.ndarray, token: Token) -> float:
    name = token.text
    index = {"x": 0, "u": 0, "red": 0, "y": 1, "v": 1, "green": 1, "z": 2, "blue": 2, "t": 3,
             "filter": 3, "transmit": 4}.get(name)
    if name == "gray" or name == "grey":
        return float(0.297 * value[0] + 0.589 * value[1] + 0.114 * value[2])
    if index is None or index >= len(value):
        raise PovError(f"{token.where}: a {len(value)}-component vector has no member .{name}")
    return float(value[index])


def _element(array: PovArray, index: int, token: Token):
    items = array.items
    if not 0 <= index < len(items):
        raise PovError(f"{token.where}: array index {index} out of range (size {len(items)})")
    item = items[index]
    if isinstance(item, list):
        return PovArray(item, array.dims[1:])
    if item is None:
        raise PovError(f"{token.where}: array element {index} was never set")
    return item


def set_element(interp, array: PovArray, indices: list[int], value, token: Token) -> None:
    items = array.items
    for k, index in enumerate(indices):
        if not isinstance(items, list) or not 0 <= index < len(items):
            raise PovError(f"{token.where}: array index {index} out of range")
        if k == len(indices) - 1:
            items[index] = value
        else:
            items = items[index]


def _unquote(text: str) -> str:
    body = text[1:-1]
    return body.replace('\\"', '"').replace("\\\\", "\\").replace("\\n", "\n")


def _str(value, length=0.0, precision=6.0) -> str:
    p = int(precision)
    text = f"{value:.{p}f}" if p >= 0 else f"{value:g}"
    width = int(length)
    if width > 0:
        text = text.rjust(width)
    elif width < 0:
        text = text.rjust(-width, "0")
    return text


def _vrotate(v, r):
    return (rotate_matrix(_pad(r, 3)) @ np.append(_pad(v, 3)[:3], 1.0))[:3]


def _vaxis_rotate(v, axis, angle):
    a = np.asarray(_pad(axis, 3)[:3], dtype=np.float64)
    a = a / np.linalg.norm(a)
    theta = math.radians(angle)
    v = _pad(v, 3)[:3]
    # Left-handed POV-Ray: the same formula as rotate about x, y, z.
    c, s = math.cos(theta), math.sin(theta)
    return v * c + np.cross(a, v) * s + a * np.dot(a, v) * (1 - c)


FUNCTIONS = {
    "abs": (abs, (1,)), "sqrt": (math.sqrt, (1,)), "pow": (math.pow, (2,)), "exp": (math.exp, (1,)),
    "ln": (math.log, (1,)), "log": (math.log10, (1,)),
    "sin": (math.sin, (1,)), "cos": (math.cos, (1,)), "tan": (math.tan, (1,)),
    "asin": (math.asin, (1,)), "acos": (math.acos, (1,)), "atan": (math.atan, (1,)),
    "atan2": (math.atan2, (2,)), "sinh": (math.sinh, (1,)), "cosh": (math.cosh, (1,)),
    "tanh": (math.tanh, (1,)), "asinh": (math.asinh, (1,)), "acosh": (math.acosh, (1,)),
    "atanh": (math.atanh, (1,)), "radians": (math.radians, (1,)), "degrees": (math.degrees, (1,)),
    "min": (min, None), "max": (max, None), "mod": (math.fmod, (2,)),
    "div": (lambda a, b: float(int(a / b)), (2,)),
    "int": (lambda a: float(int(a)), (1,)), "floor": (math.floor, (1,)), "ceil": (math.ceil, (1,)),
    "select": (lambda a, b, c, d=None: (b if a < 0 else c) if d is None else
               (b if a < 0 else c if a == 0 else d), (3, 4)),
    "vlength": (lambda v: float(np.linalg.norm(v)), (1,)),
    "vnormalize": (lambda v: v / np.linalg.norm(v), (1,)),
    "vdot": (lambda a, b: float(np.dot(_pad(a, 3)[:3], _pad(b, 3)[:3])), (2,)),
    "vcross": (lambda a, b: np.cross(_pad(a, 3)[:3], _pad(b, 3)[:3]), (2,)),
    "vrotate": (_vrotate, (2,)), "vaxis_rotate": (_vaxis_rotate, (3,)),
    "strlen": (lambda s: float(len(s)), (1,)), "str": (_str, (3,)),
    "concat": (lambda *s: "".join(s), None), "chr": (lambda c: chr(int(c)), (1,)),
    "asc": (lambda s: float(ord(s[0])) if s else 0.0, (1,)),
    "substr": (lambda s, p, n: s[int(p) - 1:int(p) - 1 + int(n)], (3,)),
    "strupr": (str.upper, (1,)), "strlwr": (str.lower, (1,)),
    "strcmp": (lambda a, b: float((a > b) - (a < b)), (2,)),
    "val": (float, (1,)), "file_exists": (lambda s: 0.0, (1,)),
    "bitwise_and": (lambda *a: float(np.bitwise_and.reduce([int(v) for v in a])), None),
    "bitwise_or": (lambda *a: float(np.bitwise_or.reduce([int(v) for v in a])), None),
}


def _seed(interp, args, token):
    interp.rand_streams.append(int(as_float(args[0], token, "seed")) & 0x7FFFFFFF or 1)
    return float(len(interp.rand_streams) - 1)


def _rand(interp, args, token):
    k = int(as_float(args[0], token, "rand"))
    if not 0 <= k < len(interp.rand_streams):
        raise PovError(f"{token.where}: rand() of a stream that seed() did not make")
    state = (interp.rand_streams[k] * 1103515245 + 12345) & 0x7FFFFFFF
    interp.rand_streams[k] = state
    return state / 0x7FFFFFFF


def _dimension_size(interp, args, token):
    array, n = args[0], int(as_float(args[1], token, "dimension_size"))
    if not isinstance(array, PovArray) or not 1 <= n <= len(array.dims):
        raise PovError(f"{token.where}: dimension_size needs an array and a dimension")
    return float(array.dims[n - 1])


def _dimensions(interp, args, token):
    return float(len(args[0].dims)) if isinstance(args[0], PovArray) else 0.0


def _not_evaluated(result):
    def call(interp, args, token):
        interp.notes.append(f"{token.where}: {token.text}() is not evaluated here "
                            f"(gives {_fmt(result) if isinstance(result, float) else '<0, 0, 0>'})")
        if token.text == "trace" and len(args) == 4:
            pass
        return result.copy() if isinstance(result, np.ndarray) else result
    return call


def _extent(which):
    def call(interp, args, token):
        from .objects import object_extent

        return object_extent(interp, args[0], token, which)
    return call


_SPECIAL = {"seed": _seed, "rand": _rand, "dimension_size": _dimension_size,
            "dimensions": _dimensions, "trace": _not_evaluated(np.zeros(3)),
            "inside": _not_evaluated(0.0), "min_extent": _extent(0), "max_extent": _extent(1)}


def parse_expression(interp, relational: bool = False):
    """One expression (comparisons only inside parentheses unless
    ``relational``)."""
    return _Parser(interp, relational).expression()


def parse_condition(interp):
    """The parenthesised condition of ``#if``, ``#while``, ``#switch``,
    ``#case``: nothing after its ``)`` is read (a directive may follow)."""
    if interp.peek_soft().text != "(":
        return parse_expression(interp, relational=True)
    parser = _Parser(interp, True)
    interp.next()
    value = parser.nested(True)
    interp.take(")", "to close the condition")
    return value


def parse_value(interp):
    """What ``#declare NAME =`` or a macro argument holds: an object, a
    texture (or finish, pigment, ...), a transform, an array, something
    braced that is kept as opaque, or an expression."""
    from . import objects

    token = interp.peek()
    if token.kind == "word" and interp.lookup(token.text) is None:
        if token.text in objects.OBJECT_KEYWORDS:
            return objects.parse_object(interp)
        if token.text in objects.MATERIAL_KEYWORDS:
            return objects.parse_material(interp)
        if token.text == "transform":
            interp.next()
            return objects.parse_transform_body(interp, token)
        if token.text == "array":
            return _parse_array(interp)
        if token.text not in FUNCTIONS and token.text not in _SPECIAL \
                and token.text not in _COLOR_KEYWORDS and token.text not in ("color", "colour") \
                and token.text not in _COMPONENTS:
            interp.next()
            if interp.peek().text == "(":  # function(a, b) { ... }
                objects.skip_parens(interp)
            if interp.peek().text == "{":
                objects.skip_braces(interp, token.text)
                from .values import Opaque
                return Opaque(token.text, token.where)
            interp.push(token)
    return parse_expression(interp)


def _parse_array(interp):
    token = interp.next()
    if interp.peek().kind == "word" and interp.peek().text == "mixed":
        interp.next()
    dims: list[int] = []
    while interp.peek_soft().text == "[":
        interp.next()
        dims.append(int(as_float(parse_expression(interp, True), token, "an array size")))
        interp.take("]", "to close the array size")
    if not dims or any(d < 0 for d in dims) or math.prod(dims) > 10_000_000:
        raise PovError(f"{token.where}: bad array size {dims}")

    def empty(ds):
        return [None] * ds[0] if len(ds) == 1 else [empty(ds[1:]) for _ in range(ds[0])]

    items = empty(dims)
    if interp.peek_soft().text == "{":
        items = _array_items(interp, dims, token)
    return PovArray(items, tuple(dims))


def _array_items(interp, dims, token):
    interp.take("{", "to open the array items")
    items = []
    while interp.peek().text != "}":
        if len(dims) > 1:
            items.append(_array_items(interp, dims[1:], token))
        else:
            items.append(parse_value(interp))
        if interp.peek().text == ",":
            interp.next()
    interp.take("}", "to close the array items")
    if len(items) != dims[0]:
        raise PovError(f"{token.where}: the array has {dims[0]} elements but {len(items)} are given")
    return items
