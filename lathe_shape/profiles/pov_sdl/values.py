"""Values of the SDL front end: numbers are Python floats, vectors and
colours numpy arrays (2 to 5 components), strings Python strings; the rest
are the classes here. Also the 4x4 matrices of POV-Ray's transforms
(row-vector maths written as column-vector matrices: ``scale``, then
``rotate``, then ``translate`` compose as ``T @ R @ S``)."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

__all__ = ["PovArray", "Macro", "Material", "Opaque", "TransformValue", "scale_matrix",
           "translate_matrix", "rotate_matrix", "matrix_from_12", "type_name"]


@dataclass
class PovArray:
    """``array[n][m]...``: nested Python lists, ``None`` where not yet set."""

    items: list
    dims: tuple[int, ...]


@dataclass
class Macro:
    """``#macro NAME(params) ... #end``: the body is ``tokens[start:end]``."""

    name: str
    params: list[str]
    tokens: list
    start: int
    end: int
    where: str


@dataclass
class Material:
    """What a texture, finish, interior or material says that matters here
    (all else is ignored)."""

    ior: float | None = None
    reflection: float | None = None
    metallic: bool = False
    color: np.ndarray | None = None
    where: str = ""

    def merged(self, other: Material | None) -> Material:
        """This material with what ``other`` sets and this one does not."""
        if other is None:
            return self
        return Material(ior=self.ior if self.ior is not None else other.ior,
                        reflection=self.reflection if self.reflection is not None else other.reflection,
                        metallic=self.metallic or other.metallic,
                        color=self.color if self.color is not None else other.color,
                        where=self.where or other.where)

    def is_empty(self) -> bool:
        return self.ior is None and self.reflection is None and not self.metallic and self.color is None


@dataclass
class Opaque:
    """A value read but not used (a function, spline, camera, ...)."""

    kind: str
    where: str


@dataclass
class TransformValue:
    """``transform { ... }``."""

    matrix: np.ndarray = field(default_factory=lambda: np.eye(4))


def type_name(value) -> str:
    """How a value is called in messages."""
    if isinstance(value, float):
        return "a number"
    if isinstance(value, np.ndarray):
        return f"a {len(value)}-component vector"
    if isinstance(value, str):
        return "a string"
    return {"PovArray": "an array", "Macro": "a macro", "Material": "a texture",
            "Opaque": f"a {getattr(value, 'kind', '?')}", "TransformValue": "a transform",
            "ObjectNode": "an object"}.get(type(value).__name__, type(value).__name__)


def scale_matrix(v: np.ndarray) -> np.ndarray:
    m = np.eye(4)
    m[0, 0], m[1, 1], m[2, 2] = v[:3]
    return m


def translate_matrix(v: np.ndarray) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = v[:3]
    return m


def rotate_matrix(v: np.ndarray) -> np.ndarray:
    """POV-Ray's ``rotate <a, b, c>``: about x by a, then y by b, then z by c
    (degrees, left-handed: positive angles turn y towards z about x, z
    towards x about y, x towards y about z)."""
    m = np.eye(4)
    for axis, angle in enumerate(np.radians(v[:3])):
        if angle == 0.0:
            continue
        c, s = math.cos(angle), math.sin(angle)
        i, j = [(1, 2), (2, 0), (0, 1)][axis]
        r = np.eye(4)
        r[i, i], r[i, j], r[j, i], r[j, j] = c, -s, s, c
        m = r @ m
    return m


def matrix_from_12(values: np.ndarray) -> np.ndarray:
    """POV-Ray's ``matrix <v00, v01, v02, v10, ..., v32>``: rows of a
    row-vector matrix, the last row the translation."""
    rows = np.asarray(values, dtype=np.float64).reshape(4, 3)
    m = np.eye(4)
    m[:3, :3] = rows[:3].T
    m[:3, 3] = rows[3]
    return m
