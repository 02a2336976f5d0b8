"""Objects of a POV-Ray scene as read by the SDL front end: ``lathe`` and
``sor`` blocks in full, CSG (``union``, ``merge``, ``difference``,
``intersection``) and ``object { }`` with their transforms and materials,
every other object kept as a placeholder (``sphere``, ``box``, ...).

Transforms (``scale``, ``rotate``, ``translate``, ``matrix``, ``transform
{ }`` or a declared transform, with ``inverse``) compose in order as 4x4
matrices acting on column vectors, POV-Ray axes. Materials keep what
:class:`~.values.Material` holds: a literal or declared ``interior { ior
}``, ``finish { reflection, metallic }`` and the first pigment colour.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from . import expressions as ex
from .tokens import PovError, Token
from .values import (
    Material,
    TransformValue,
    matrix_from_12,
    rotate_matrix,
    scale_matrix,
    translate_matrix,
    type_name,
)

__all__ = ["LatheBlock", "ObjectNode", "OBJECT_KEYWORDS", "MATERIAL_KEYWORDS", "SPLINE_KINDS",
           "parse_object", "parse_material", "parse_transform_body", "skip_braces", "skip_parens",
           "object_extent"]

#: POV-Ray spline keywords and the profile kinds they become.
SPLINE_KINDS = {"linear_spline": "polyline", "quadratic_spline": "quadratic",
                "cubic_spline": "catmull_rom", "bezier_spline": "bezier"}

CSG_KEYWORDS = ("union", "merge", "difference", "intersection")
OTHER_OBJECTS = ("sphere", "box", "cylinder", "cone", "torus", "plane", "disc", "triangle",
                 "smooth_triangle", "polygon", "prism", "isosurface", "parametric", "superellipsoid",
                 "text", "mesh", "mesh2", "blob", "height_field", "bicubic_patch", "julia_fractal",
                 "quadric", "cubic", "quartic", "poly", "polynomial", "sphere_sweep", "lemon", "ovus",
                 "light_source", "light_group")
OBJECT_KEYWORDS = ("lathe", "sor", "object", *CSG_KEYWORDS, *OTHER_OBJECTS)
MATERIAL_KEYWORDS = ("texture", "pigment", "finish", "interior", "material", "normal")
_FLAGS = ("hollow", "no_shadow", "no_image", "no_reflection", "double_illuminate", "uv_mapping",
          "no_radiosity", "inverse", "sturm")


@dataclass
class LatheBlock:
    """One evaluated ``lathe`` or ``sor`` block (its own transforms are on
    its :class:`ObjectNode`)."""

    object: str
    kind: str
    points: np.ndarray
    where: str
    name_hint: str | None
    open_sheet: bool = False
    sturm: bool = False
    notes: list[str] = field(default_factory=list)
    error: str | None = None
    token: Token | None = None


@dataclass
class ObjectNode:
    kind: str
    where: str
    transform: np.ndarray = field(default_factory=lambda: np.eye(4))
    children: list = field(default_factory=list)
    block: LatheBlock | None = None
    material: Material | None = None


def skip_braces(interp, what: str) -> None:
    """Skip ``{ ... }`` (directives inside still act)."""
    start = interp.take("{", f"after {what}")
    depth = 1
    while depth:
        token = interp.next()
        if token.kind == "end":
            raise PovError(f"{start.where}: the '{{' of {what} is not closed")
        if token.kind == "symbol":
            depth += {"{": 1, "}": -1}.get(token.text, 0)


def skip_parens(interp) -> None:
    start = interp.take("(", "")
    depth = 1
    while depth:
        token = interp.next()
        if token.kind == "end":
            raise PovError(f"{start.where}: '(' is not closed")
        if token.kind == "symbol":
            depth += {"(": 1, ")": -1}.get(token.text, 0)


def _is_keyword(interp, token: Token, words) -> bool:
    return token.kind == "word" and token.text in words and interp.lookup(token.text) is None


def parse_object(interp) -> ObjectNode:
    """One object statement (its keyword next)."""
    token = interp.next()
    kind = token.text
    if kind in ("lathe", "sor"):
        return _parse_lathe(interp, token)
    if kind in OTHER_OBJECTS:
        skip_braces(interp, kind)
        return ObjectNode(kind, token.where)
    interp.take("{", f"after '{kind}'")
    node = ObjectNode(kind, token.where)
    if kind == "object":
        first = interp.peek()
        value = interp.lookup(first.text) if first.kind == "word" else None
        if isinstance(value, ObjectNode):
            interp.next()
            node.children.append(value)
        elif value is not None:
            value = ex.parse_expression(interp)
            if not isinstance(value, ObjectNode):
                raise PovError(f"{first.where}: object {{ }} needs an object, got "
                               f"{type_name(value)}")
            node.children.append(value)
        elif _is_keyword(interp, first, OBJECT_KEYWORDS):
            node.children.append(parse_object(interp))
        else:
            what = "the end of the file" if first.kind == "end" else repr(first.text)
            raise PovError(f"{first.where}: object {{ }} needs an object or a declared object "
                           f"name first, got {what}")
    while True:
        nxt = interp.peek()
        if node.kind in CSG_KEYWORDS and _is_keyword(interp, nxt, OBJECT_KEYWORDS):
            node.children.append(parse_object(interp))
            continue
        if nxt.text == "}" and nxt.kind == "symbol":
            interp.next()
            return node
        _modifier(interp, node, None, token)


def _parse_lathe(interp, token: Token) -> ObjectNode:
    """A ``lathe`` or ``sor`` block; an error inside it fails this block
    only (its node carries the error, reading goes on after its '}')."""
    obj = token.text
    interp.evaluated.add(id(token))
    brace = interp.take("{", f"after '{obj}'")
    frame = interp.frames[-1] if interp.frames else None
    pos = frame.pos if frame is not None else 0
    state = interp.depth()
    hint = interp.declaring[-1] if interp.declaring else None
    block = LatheBlock(obj, "sor", np.zeros((0, 2)), token.where, hint, token=token)
    node = ObjectNode(obj, token.where, block=block)
    try:
        _read_lathe(interp, node, block)
    except (PovError, ValueError, TypeError, IndexError, ArithmeticError, RecursionError) as e:
        block.error = str(e) if isinstance(e, PovError) else \
            f"{interp.last.where}: {type(e).__name__}: {e}"
        interp.unwind(state)
        if frame is None or pos == 0 or frame.tokens[pos - 1] is not brace:
            raise
        frame.pos = pos
        depth = 1
        while depth and frame.pos < frame.end:
            t = frame.tokens[frame.pos]
            frame.pos += 1
            if t.kind == "symbol":
                depth += {"{": 1, "}": -1}.get(t.text, 0)
    interp.registry.append(node)
    return node


def _read_lathe(interp, node: ObjectNode, block: LatheBlock) -> None:
    obj = block.object
    kind = "sor"
    if obj == "lathe":
        kind = "polyline"
        nxt = interp.peek()
        if nxt.kind == "word" and nxt.text in SPLINE_KINDS:
            kind = SPLINE_KINDS[interp.next().text]
        elif nxt.kind == "word" and not interp.defined(nxt.text) and nxt.text not in ex.FUNCTIONS:
            raise PovError(f"{nxt.where}: unknown lathe spline type '{nxt.text}' (expected one of: "
                           f"{', '.join(SPLINE_KINDS)}, or the point count)")
    block.kind = kind
    count_token = interp.peek()
    if count_token.kind == "symbol" and count_token.text == "<":
        raise PovError(f"{count_token.where}: expected the point count of the {obj}, got a point "
                       f"('<')")
    count = ex.as_float(ex.parse_expression(interp), count_token, f"the point count of the {obj}")
    if count != int(count) or count < 2:
        raise PovError(f"{count_token.where}: the point count of the {obj} must be a whole number "
                       f">= 2, got {count:g}")
    if count > 1_000_000:
        raise PovError(f"{count_token.where}: the {obj} announces {count:g} points (at most 1,000,000)")
    points = []
    for k in range(int(count)):
        if interp.peek().text == ",":
            interp.next()
        nxt = interp.peek()
        if nxt.kind == "end" or (nxt.kind == "symbol" and nxt.text == "}") or \
                _is_keyword(interp, nxt, _FLAGS + MATERIAL_KEYWORDS + ("scale", "rotate", "translate",
                                                                       "matrix", "transform", "open")):
            got = "the end of the file" if nxt.kind == "end" else repr(nxt.text)
            raise PovError(f"{nxt.where}: the {obj} announces {int(count)} points but point {k + 1} "
                           f"is missing (got {got})")
        value = ex.parse_expression(interp)
        if isinstance(value, np.ndarray) and len(value) > 2:
            raise PovError(f"{nxt.where}: point {k + 1} of the {obj} has {len(value)} components, "
                           f"expected 2")
        points.append(ex.as_vector(value, 2, nxt, f"point {k + 1} of the {obj}"))
    block.points = np.array(points, dtype=np.float64)
    skipped: dict[str, int] = {}
    while True:
        nxt = interp.peek()
        if nxt.kind == "end":
            raise PovError(f"{nxt.where}: the {obj} block opened at {block.where} is not closed "
                           f"(missing '}}')")
        if nxt.kind == "symbol" and nxt.text == "}":
            interp.next()
            break
        _modifier(interp, node, skipped, nxt)
    block.notes += list(skipped.values())


def _modifier(interp, node: ObjectNode, skipped: dict | None, owner: Token) -> None:
    """One object modifier of ``node``."""
    token = interp.next()
    word = token.text
    block = node.block
    if token.kind == "symbol" and word in ",;":
        return
    if token.kind == "end":
        raise PovError(f"{owner.where}: the {node.kind} block opened at {node.where} is not closed "
                       f"(missing '}}')")
    if token.kind == "word" and interp.lookup(word) is None:
        if word in ("scale", "rotate", "translate", "matrix"):
            step = _transform_step(interp, word, token)
            node.transform = step @ node.transform
            if word == "scale" and _singular(node.transform):
                raise PovError(f"{token.where}: scale {_fmt_scale(step)}: the {node.kind}'s "
                               f"transform becomes singular (a zero or vanishing scale component "
                               f"flattens the shape; Mitsuba cannot load it)")
            return
        if word == "transform":
            node.transform = _transform_value(interp, token) @ node.transform
            return
        if word in MATERIAL_KEYWORDS:
            if skipped is not None:
                skipped.setdefault(word, f"line {token.line}: '{word}' ignored by the profile "
                                         f"(--scene reads the material)")
            interp.push(token)
            material = parse_material(interp)
            node.material = material.merged(node.material)
            return
        if word == "open":
            if block is None or block.object != "sor":
                raise PovError(f"{token.where}: 'open' is a sor modifier (a lathe is open when its "
                               f"curve is)")
            block.open_sheet = True
            return
        if word == "sturm" and block is not None:
            block.sturm = True
            block.notes.append("sturm: not needed (the exact kernel brackets every root)")
            return
    if skipped is not None and token.kind == "word":
        skipped.setdefault(word, f"line {token.line}: '{word}' ignored")
    if interp.peek().text == "{":
        skip_braces(interp, word)
        return
    nxt = interp.peek_soft()
    if token.kind == "word" and interp.lookup(word) is None and word not in _FLAGS and (
            nxt.kind == "number" or nxt.text in ("<", "(", "-", "+")):
        ex.parse_expression(interp)


def _transform_step(interp, op: str, token: Token) -> np.ndarray:
    if op == "matrix":
        interp.take("<", "to open the matrix")
        values = [ex.as_float(ex.parse_expression(interp), token, "a matrix entry")]
        while interp.peek().text == ",":
            interp.next()
            values.append(ex.as_float(ex.parse_expression(interp), token, "a matrix entry"))
        interp.take(">", "to close the matrix")
        if len(values) != 12:
            raise PovError(f"{token.where}: matrix needs 12 numbers, got {len(values)}")
        return matrix_from_12(np.array(values))
    value = ex.parse_expression(interp)
    if op == "scale":
        if isinstance(value, float):
            return scale_matrix(np.full(3, value))
        return scale_matrix(ex.as_vector(value, 3, token, "scale"))
    v = ex.as_vector(value, 3, token, op)
    return translate_matrix(v) if op == "translate" else rotate_matrix(v)


def _transform_value(interp, token: Token) -> np.ndarray:
    nxt = interp.peek()
    value = interp.lookup(nxt.text) if nxt.kind == "word" else None
    if isinstance(value, TransformValue):
        interp.next()
        return value.matrix
    return parse_transform_body(interp, token).matrix


def parse_transform_body(interp, token: Token) -> TransformValue:
    """``{ scale ... rotate ... translate ... matrix ... inverse }`` after
    the word ``transform``."""
    interp.take("{", "after 'transform'")
    m, inverse = np.eye(4), False
    while True:
        t = interp.next()
        if t.kind == "symbol" and t.text == "}":
            break
        if t.kind == "end":
            raise PovError(f"{token.where}: transform {{ is not closed")
        if t.text in ("scale", "rotate", "translate", "matrix"):
            m = _transform_step(interp, t.text, t) @ m
        elif t.text == "inverse":
            inverse = True
        elif t.text == "transform":
            m = _transform_value(interp, t) @ m
        elif isinstance(interp.lookup(t.text), TransformValue):
            m = interp.lookup(t.text).matrix @ m
        else:
            raise PovError(f"{t.where}: unexpected {t.text!r} in transform {{ }}")
    if inverse:
        m = np.linalg.inv(m)
    return TransformValue(m)


def parse_material(interp) -> Material:
    """A ``texture``, ``pigment``, ``finish``, ``interior``, ``material`` or
    ``normal`` block (the keyword next): what :class:`Material` keeps."""
    token = interp.next()
    material = Material(where=token.where)
    if interp.peek().text != "{":
        return material
    interp.next()
    depth, pigment_depth = 1, 1 if token.text == "pigment" else None
    while depth:
        t = interp.next()
        if t.kind == "end":
            raise PovError(f"{token.where}: the '{{' of {token.text} is not closed")
        if t.kind == "symbol":
            depth += {"{": 1, "}": -1}.get(t.text, 0)
            if pigment_depth is not None and depth < pigment_depth:
                pigment_depth = None
            continue
        if t.kind != "word":
            continue
        value = interp.lookup(t.text)
        if isinstance(value, Material):
            material = material.merged(value) if not material.is_empty() else value.merged(material)
            continue
        if value is not None:
            if isinstance(value, np.ndarray) and pigment_depth is not None and material.color is None:
                material.color = value[:3].copy() if len(value) >= 3 else None
            continue
        if t.text == "pigment":
            if interp.peek().text == "{":
                interp.next()
                depth += 1
                pigment_depth = depth
        elif t.text == "ior":
            material.ior = ex.as_float(ex.parse_expression(interp), t, "ior")
        elif t.text == "reflection":
            if interp.peek().text == "{":
                interp.next()
                depth += 1
            v = ex.parse_expression(interp)
            material.reflection = float(np.max(v[:3])) if isinstance(v, np.ndarray) else v
        elif t.text == "metallic":
            material.metallic = True
        elif t.text in ("color", "colour", "rgb", "rgbf", "rgbt", "rgbft", "srgb"):
            interp.push(t)
            v = ex.parse_expression(interp)
            if pigment_depth is not None and material.color is None and isinstance(v, np.ndarray):
                material.color = v[:3].copy()
    return material


def _singular(m: np.ndarray) -> bool:
    """Whether the linear part of ``m`` is singular or too nearly so for a
    lathe's ``to_world`` (the test of ``plugin.params.check_transform``)."""
    linear = m[:3, :3]
    if not np.isfinite(linear).all():
        return True
    return abs(np.linalg.det(linear)) <= 1e-9 * float(np.prod(np.linalg.norm(linear, axis=0)))


def _fmt_scale(m: np.ndarray) -> str:
    return "<" + ", ".join(f"{v:g}" for v in np.diag(m)[:3]) + ">"


def object_extent(interp, value, token: Token, which: int) -> np.ndarray:
    """``min_extent``/``max_extent`` of a lathe or sor object (the box of
    its revolved profile, transformed); zeros, with a note, otherwise."""
    node = value
    m = np.eye(4)
    while isinstance(node, ObjectNode) and node.kind == "object" and node.children:
        m = m @ node.transform
        node = node.children[0]
    if not isinstance(node, ObjectNode) or node.block is None or node.block.error or \
            not len(node.block.points):
        interp.notes.append(f"{token.where}: {token.text}() of an object other than a lathe or "
                            f"sor is not evaluated (gives <0, 0, 0>)")
        return np.zeros(3)
    m = m @ node.transform
    p = node.block.points
    r, lo, hi = float(np.abs(p[:, 0]).max()), float(p[:, 1].min()), float(p[:, 1].max())
    corners = np.array([[sx * r, h, sz * r, 1.0] for sx in (-1, 1) for sz in (-1, 1) for h in (lo, hi)])
    world = (m @ corners.T).T[:, :3]
    return world.min(axis=0) if which == 0 else world.max(axis=0)
