"""The walk over a whole scene: top-level statements read one at a time
(an error fails that statement only, reading resumes after it), objects
flattened into placed lathe and sor instances, and every block of the
scene's own files accounted for.

Each block read is one :class:`SceneObject` with its placements
(:class:`Placement`: the world transform, POV-Ray axes, composed from the
block's own transforms and those of every enclosing ``object``, CSG or
declared object it is used through; the material that applies; what an
enclosing CSG dropped). A block read but never placed in the scene (a
declared object not used) gets one placement at its own transforms, with a
note. A block of the scene's own files that was never read (a ``#switch``
case or ``#if`` branch not taken, an uncalled macro) is read afterwards
with the symbols as they stand at the end, and placed at its own
transforms, with a note.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field

import numpy as np

from .interpreter import INCLUDE_PATH, Interpreter
from .objects import CSG_KEYWORDS, OBJECT_KEYWORDS, LatheBlock, ObjectNode, parse_object, skip_braces
from .tokens import PovError
from .values import Material

__all__ = ["Placement", "SceneObject", "SceneResult", "walk_scene"]


@dataclass
class Placement:
    transform: np.ndarray
    material: Material | None
    dropped: list[str] = field(default_factory=list)


@dataclass
class SceneObject:
    block: LatheBlock
    placements: list[Placement] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    error: str | None = None
    name: str = ""


@dataclass
class SceneResult:
    path: str
    objects: list[SceneObject]
    notes: list[str]
    files: list[str]


def _top_level_skip(interp, frame, pos: int) -> None:
    """After an error: skip the statement that began at ``frame.tokens[pos]``
    (raw tokens, to the end of its braces or its ';')."""
    frame.pos = pos + 1
    depth = 0
    while frame.pos < frame.end:
        t = frame.tokens[frame.pos]
        if depth == 0 and t.kind == "directive":
            return
        frame.pos += 1
        if t.kind == "symbol":
            if t.text == "{":
                depth += 1
            elif t.text == "}":
                depth -= 1
                if depth <= 0:
                    return
            elif t.text == ";" and depth == 0:
                return


def walk_scene(path: str, include_path: tuple[str, ...] = INCLUDE_PATH,
               defines: dict | None = None) -> SceneResult:
    """Read the scene at ``path`` (see the module docstring). Raises
    :class:`PovError` only when the file itself cannot be read."""
    interp = Interpreter(os.fspath(path), include_path, dict(defines or {}))
    instances: list[tuple[ObjectNode, Placement]] = []
    notes = interp.notes
    failed_statements: dict[int, str] = {}
    resumed_at = None  # where reading went on after the last error whose statement's file had ended
    while True:
        frame = interp.frames[-1] if interp.frames else None
        pos = frame.pos if frame is not None else 0
        state = interp.depth()
        seen = len(interp.registry)
        peeked = False  # the directives before the statement's first token ran
        try:
            token = interp.peek()
            peeked, seen = True, len(interp.registry)
            if token.kind == "end":
                break
            if token.kind == "word" and token.text in OBJECT_KEYWORDS and interp.lookup(token.text) is None:
                node = parse_object(interp)
                _flatten(node, np.eye(4), None, [], instances)
            else:
                interp.next()
                if interp.peek_soft().text == "{":
                    skip_braces(interp, token.text)
        except (PovError, ValueError, TypeError, IndexError, ArithmeticError, RecursionError) as e:
            if not isinstance(e, PovError):
                e = PovError(f"{interp.last.where}: {type(e).__name__}: {e}")
            notes.append(f"{e}")
            # The objects of the statement that failed (a directive that
            # failed while the next statement was looked for: its own only)
            first = seen if peeked else max(seen, interp.statement_registry)
            for node in interp.registry[first:]:
                failed_statements[id(node)] = str(e)
            if frame is None or frame not in interp.frames[:state[0]]:
                # The file of the last statement ended, and a directive of
                # the file that included it failed (a missing #include): go
                # on after it, where the reader is
                here = (id(interp.frames[-1]), interp.frames[-1].pos) if interp.frames else None
                if here is None or here == resumed_at:
                    break
                resumed_at = here
                continue  # (the tokens read ahead, in pushback, come next)
            if not peeked and interp.statement_directive == "#include":
                # An #include that failed was read to its end, its name
                # (and the token after it, read ahead), and opened nothing:
                # the next statement follows, in the #if or #while the
                # include sat in (nothing to unwind). Skipping "its
                # statement" from there dropped the object after a missing
                # include.
                continue
            interp.unwind(state)
            _top_level_skip(interp, frame, pos)
    main_files = [f for f in interp.files if not any(
        os.path.realpath(f).startswith(os.path.realpath(p) + os.sep) for p in include_path)]
    dormant = _read_dormant(interp, main_files)
    return SceneResult(os.fspath(path), _objects(interp, instances, failed_statements, dormant),
                       list(dict.fromkeys(notes)), interp.files)


def _flatten(node: ObjectNode, parent: np.ndarray, material: Material | None, dropped: list[str],
             out: list) -> None:
    m = parent @ node.transform
    if node.material is not None:
        material = node.material.merged(material)
    if node.block is not None:
        out.append((node, Placement(m, material, list(dropped))))
        return
    if node.kind in CSG_KEYWORDS:
        has = [_has_lathe(c) for c in node.children]
        others = sum(not h for h in has)
        for k, child in enumerate(node.children):
            if not has[k]:
                continue
            note = []
            if others:
                note.append(f"{node.kind} at {node.where}: {others} other object"
                            f"{'s' if others != 1 else ''} not imported")
            if node.kind == "difference" and k > 0:
                note.append(f"difference at {node.where}: this object is cut away in POV-Ray, "
                            f"imported as a solid")
            _flatten(child, m, material, dropped + note, out)
    elif node.kind == "object":
        for child in node.children:
            _flatten(child, m, material, dropped, out)


def _has_lathe(node: ObjectNode) -> bool:
    return node.block is not None or any(_has_lathe(c) for c in node.children)


def _read_dormant(interp, files: list[str]) -> list[ObjectNode]:
    """Blocks of ``files`` never read during the walk (module docstring)."""
    found: list[ObjectNode] = []
    for path in files:
        tokens = interp.read_file(path, None)
        for k, t in enumerate(tokens[:-1]):
            if t.kind != "word" or t.text not in ("lathe", "sor") or tokens[k + 1].text != "{" \
                    or id(t) in interp.evaluated:
                continue
            state = interp.depth()
            before = len(interp.registry)
            interp.run_dormant(tokens, k, len(tokens))
            try:
                parse_object(interp)
            except (PovError, ValueError, TypeError, IndexError, ArithmeticError, RecursionError) as e:
                block = LatheBlock(t.text, "sor", np.zeros((0, 2)), t.where, None, error=str(e), token=t)
                interp.registry.append(ObjectNode(t.text, t.where, block=block))
            interp.unwind(state)
            found.extend(interp.registry[before:])
    return found


def _objects(interp, instances, failed: dict[int, str], dormant: list[ObjectNode]) -> list[SceneObject]:
    """One SceneObject per distinct block (same place, kind and points)."""
    objects: dict[tuple, SceneObject] = {}
    by_node: dict[int, SceneObject] = {}
    for node in interp.registry:
        b = node.block
        key = (b.where, b.kind, b.points.tobytes(), b.open_sheet, b.error)
        if key not in objects:
            objects[key] = SceneObject(b, error=b.error or failed.get(id(node)))
        by_node[id(node)] = objects[key]
    for node, placement in instances:
        by_node[id(node)].placements.append(placement)
    dormant_ids = {id(n) for n in dormant}
    for node in interp.registry:
        obj = by_node[id(node)]
        if obj.placements or obj.error:
            continue
        obj.placements.append(Placement(node.transform.copy(), node.material))
        if id(node) in dormant_ids:
            obj.notes.append("not part of the rendered scene (in a #switch case, #if branch or "
                             "macro that is not evaluated): imported at its own transforms")
        else:
            obj.notes.append("declared but not used in the scene: imported at its own transforms")
    result = list(objects.values())
    _name(result, os.path.splitext(os.path.basename(interp.path))[0])
    return result


def _name(objects: list[SceneObject], stem: str) -> None:
    counts: dict[str, int] = {}
    used: set[str] = set()
    for obj in objects:
        b = obj.block
        counts[b.object] = counts.get(b.object, 0) + 1
        name = b.name_hint or f"{stem}_{b.object}{counts[b.object]}"
        unique, k = name, 1
        while unique.lower() in used:
            k += 1
            unique = f"{name}_{k}"
        if unique != name:
            obj.notes.append(f"the name '{name}' is taken by an earlier object: written as '{unique}'")
        used.add(unique.lower())
        obj.name = unique
