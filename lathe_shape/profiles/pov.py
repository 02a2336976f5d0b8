"""The ``lathe`` and ``sor`` objects of a POV-Ray scene, as profiles
placed in the world (the reading itself is :mod:`.pov_sdl`, a bounded SDL
front end: expressions, declarations, conditionals, loops, macros,
includes, object transforms and CSG).

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

import os
from dataclasses import dataclass, field

import numpy as np

from .bspline import evaluate
from .pov_sdl import Material, PovError, walk_scene
from .pov_sdl.objects import SPLINE_KINDS
from .spline_kinds import curve_form, kind_coefficients, to_bspline_controls

__all__ = ["PovError", "PovBlock", "SPLINE_KINDS", "read_pov_blocks", "read_pov_objects", "to_world",
           "is_open", "lathe_snippet"]

#: The y/z swap between POV-Ray's and Mitsuba's axes (module docstring).
_SWAP = np.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0], [0, 1.0, 0, 0], [0, 0, 0, 1.0]])


@dataclass
class PovBlock:
    """One ``lathe`` or ``sor`` object of a scene."""

    #: The declared name (of the block or of the object it is declared in),
    #: else ``<scene stem>_<object><index>``; unique within the scene.
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
    #: 4x4 POV-Ray object-to-world transform of the first placement.
    transform: np.ndarray
    #: ``file:line`` of the block's keyword.
    where: str
    #: Statements that were skipped, and other remarks.
    notes: list[str] = field(default_factory=list)
    #: Every placement's transform (the first is :attr:`transform`).
    transforms: list[np.ndarray] = field(default_factory=list)
    #: The material of the first placement, if any.
    material: Material | None = None
    #: Why the object cannot be imported (then the rest may be empty).
    error: str | None = None


def read_pov_objects(path: str | os.PathLike,
                     defines: dict | None = None) -> tuple[list[PovBlock], list[str]]:
    """Every ``lathe`` and ``sor`` object of a scene, each read (or failed,
    :attr:`PovBlock.error`) on its own, and the scene's notes. Raises
    :class:`PovError` only when the file cannot be read."""
    result = walk_scene(os.fspath(path), defines=defines)
    blocks = []
    for obj in result.objects:
        b = obj.block
        placements = obj.placements
        first = placements[0] if placements else None
        notes = list(b.notes) + list(obj.notes)
        if first is not None:
            notes += first.dropped
        block = PovBlock(name=obj.name, object=b.object, kind=b.kind, points=b.points,
                         open_sheet=b.open_sheet, sturm=b.sturm,
                         transform=first.transform if first is not None else np.eye(4),
                         where=b.where, notes=list(dict.fromkeys(notes)),
                         transforms=[p.transform for p in placements],
                         material=first.material if first is not None else None, error=obj.error)
        if block.error is None and b.object == "lathe":
            try:
                block.open_sheet = is_open(b.kind, b.points, b.where)
            except ValueError as e:
                block.error = str(e)
            if block.open_sheet:
                block.notes.append("the curve does not close (nor has both ends on the axis): "
                                   "written as an open sheet")
        blocks.append(block)
    return blocks, result.notes


def read_pov_blocks(path: str | os.PathLike) -> list[PovBlock]:
    """Every ``lathe`` and ``sor`` object of a POV-Ray scene (see
    :func:`read_pov_objects`); raises :class:`PovError` for the first one
    that cannot be read."""
    blocks, _ = read_pov_objects(path)
    for block in blocks:
        if block.error is not None:
            raise PovError(block.error)
    return blocks


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


def lathe_snippet(block: PovBlock, filename: str, transform: np.ndarray | None = None,
                  shape_id: str | None = None, kind: str | None = None,
                  open_sheet: bool | None = None) -> str:
    """A Mitsuba ``<shape type="lathe">`` element for ``block``, whose
    profile CSV is ``filename`` (relative to the scene file); by default at
    the block's first placement, with its id, kind and form."""
    transform = block.transform if transform is None else transform
    shape_id = block.name if shape_id is None else shape_id
    kind = block.kind if kind is None else kind
    open_sheet = block.open_sheet if open_sheet is None else open_sheet
    matrix = " ".join(f"{v:.9g}" for v in to_world(transform).ravel())
    return (f"<!-- POV-Ray {block.object} '{block.name}' of {block.where}; POV-Ray (x, y, z) is "
            f"Mitsuba (x, z, y) (left-handed y-up to right-handed z-up). Add a <bsdf>. -->\n"
            f'<shape type="lathe" id="{shape_id}">\n'
            f'    <string name="filename" value="{filename}"/>\n'
            f'    <string name="kind" value="{kind}"/>\n'
            f'    <boolean name="open" value="{str(open_sheet).lower()}"/>\n'
            f'    <transform name="to_world">\n'
            f'        <matrix value="{matrix}"/>\n'
            f"    </transform>\n"
            f"</shape>\n")
