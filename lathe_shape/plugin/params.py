"""Reading plugin parameters: typed values and transforms, checked, with
errors that name the plugin and the parameter."""

from __future__ import annotations

import mitsuba as mi
import numpy as np

__all__ = ["CAUSTIC_CAMERA_CHAINS", "CAUSTIC_PATHS", "TRACEABLE_SCALES", "check_traceable_scale",
           "check_transform", "describe_lathe", "path_parameters", "transform_property", "typed_property"]

#: Range of a lathe's transform scale factors, and of its size in the world
#: (profile size times scale), that the float32 exact kernels trace: beyond
#: it world positions, ray parameters or the local frame's directions
#: under- or overflow float32 (measured: hits fail from about 1e-38 and
#: 1e+35 on; issue 24, item 10). Mitsuba's own mesh intersection is
#: narrower (the reference mesh misses from about 1e-20 and 1e+13 on).
TRACEABLE_SCALES = (1e-30, 1e30)

#: ``lathe_path``'s defaults of ``caustic_paths`` (light particles per camera
#: sample) and ``caustic_camera_chains`` (share of the particles seen only
#: through glass that solve their chain to the camera). The glass pixels'
#: error hardly depends on them (the bottle at 256 spp: 0.0476-0.0481 for
#: 0.01-0.05 particles per sample, plain 0.0533), the cost does; the
#: caustic region's error does, less than 1/sqrt of the particles
#: (docs/benchmarks.md).
CAUSTIC_PATHS, CAUSTIC_CAMERA_CHAINS = 0.03, 0.3


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


def path_parameters(props: mi.Properties, who: str, max_depth_default: int = -1) -> tuple[int, int, bool]:
    """``max_depth`` (-1: infinite, returned as 0xFFFFFFFF; default
    ``max_depth_default``), ``rr_depth`` and ``hide_emitters`` of a path
    tracer, as Mitsuba's ``path`` reads them, with errors naming ``who``."""
    max_depth = typed_property(props, "max_depth", int, max_depth_default, who)
    if max_depth < -1:
        raise ValueError(f"{who}: parameter 'max_depth' must be -1 (infinite) or >= 0, got {max_depth}")
    rr_depth = typed_property(props, "rr_depth", int, 5, who)
    if rr_depth <= 0:
        raise ValueError(f"{who}: parameter 'rr_depth' must be > 0, got {rr_depth}")
    hide_emitters = typed_property(props, "hide_emitters", bool, False, who)
    return (0xFFFFFFFF if max_depth == -1 else max_depth), rr_depth, hide_emitters


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


def check_traceable_scale(matrix: np.ndarray, size: float, who: str) -> None:
    """The transform's scale factors (singular values of its linear part)
    and the lathe's world size (``size``, the profile's local extent, times
    them) within :data:`TRACEABLE_SCALES`; a ValueError names ``who`` and
    the supported range otherwise."""
    lo, hi = TRACEABLE_SCALES
    factors = np.linalg.svd(matrix[:3, :3], compute_uv=False)
    small, large = float(factors.min()), float(factors.max())
    for what, value in (("scale factor", small), ("scale factor", large),
                        ("world size (profile size times scale)", size * small),
                        ("world size (profile size times scale)", size * large)):
        if not lo <= value <= hi:
            raise ValueError(f"{who}: the lathe's {what} {value:.3g} is outside the range the float32 "
                             f"exact kernels can trace ({lo:g} .. {hi:g}; the profile's size is "
                             f"{size:.3g}, the transform's scale factors {small:.3g} .. {large:.3g})")
