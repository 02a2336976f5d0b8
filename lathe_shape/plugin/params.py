"""Reading plugin parameters: typed values and transforms, checked, with
errors that name the plugin and the parameter."""

from __future__ import annotations

import mitsuba as mi
import numpy as np

__all__ = ["check_transform", "describe_lathe", "transform_property", "typed_property"]


def describe_lathe(props: mi.Properties) -> str:
    """``lathe 'ID'`` (or ``lathe``) for error messages."""
    name = props.id()
    return f"lathe '{name}'" if name else "lathe"


def typed_property(props: mi.Properties, name: str, kind: type, default, who: str):
    """``props[name]`` checked to be a ``kind`` (bool, int, float or str):
    the XML tag must match, e.g. ``<boolean name="smooth" value="false"/>``
    (a ``<string>`` "false" would otherwise read as true)."""
    value = props.get(name, default)
    ok = isinstance(value, kind) and not (kind is int and isinstance(value, bool))
    if kind is float and isinstance(value, int) and not isinstance(value, bool):
        value, ok = float(value), True
    if not ok:
        tag = {bool: "boolean", int: "integer", float: "float", str: "string"}[kind]
        raise ValueError(f"{who}: parameter '{name}' must be given as <{tag}>, got {value!r}")
    return value


def transform_property(props: mi.Properties, name: str, who: str) -> np.ndarray:
    """``props[name]`` as a (4, 4) float64 matrix (identity when absent);
    it must be given as ``<transform>``."""
    value = props.get(name, mi.ScalarTransform4f())
    # Projective ones are read too, so that check_transform can say what is wrong
    kinds = (mi.ScalarTransform4f, mi.ScalarTransform4d, mi.ScalarProjectiveTransform4f,
             mi.ScalarProjectiveTransform4d)
    if not isinstance(value, kinds):
        raise ValueError(f"{who}: parameter '{name}' must be given as <transform>, got {value!r}")
    matrix = np.array(value.matrix, dtype=np.float64)
    check_transform(matrix, f"{who}: parameter '{name}'")
    return matrix


def check_transform(matrix: np.ndarray, who: str) -> None:
    """A usable local-to-world transform: finite, affine, invertible."""
    if not np.isfinite(matrix).all():
        raise ValueError(f"{who}: the transform has non-finite entries")
    if not np.allclose(matrix[3], [0.0, 0.0, 0.0, 1.0]):
        row = " ".join(f"{x:g}" for x in matrix[3])
        raise ValueError(f"{who}: the transform is projective (bottom row {row}); a lathe's "
                         f"transform must be affine, with bottom row 0 0 0 1")
    linear = matrix[:3, :3]
    # Relative to the product of the column lengths (Hadamard's bound on the
    # determinant), so that a uniform scale of any size is accepted.
    if abs(np.linalg.det(linear)) <= 1e-9 * float(np.prod(np.linalg.norm(linear, axis=0))):
        raise ValueError(f"{who}: the transform is singular (a zero scale?)")
