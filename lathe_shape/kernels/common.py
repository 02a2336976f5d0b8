"""Result types shared by the intersection kernels.

Both kernels report a hit as ``(t, seg, u, valid)`` and the local geometry at
a hit as ``(n, sh_n, uv, dp_du, dp_dv)``. The classes are Dr.Jit structs
(usable with ``dr.select``, ``dr.zeros`` and as loop state) whose field types
come from the active Mitsuba variant, so the kernels can be imported before
``mi.set_variant``.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi

__all__ = ["LatheHit", "LatheGeometry"]


class _VariantStruct(type):
    """Metaclass: ``DRJIT_STRUCT`` built from ``_FIELDS`` (Mitsuba type
    names) for the variant active at the time of use."""

    @property
    def DRJIT_STRUCT(cls) -> dict:  # noqa: N802 (Dr.Jit's name)
        return {key: getattr(mi, name) for key, name in cls._FIELDS.items()}


class LatheHit(metaclass=_VariantStruct):
    """Nearest hit of a local-frame ray: ``t`` (units of the ray direction,
    inf on a miss), profile segment ``seg``, position ``u`` in [0, 1] along
    the segment (the curve parameter for B-splines), and ``valid``."""

    _FIELDS = {"t": "Float", "seg": "UInt32", "u": "Float", "valid": "Bool"}

    def __init__(self, t=None, seg=None, u=None, valid=None) -> None:
        self.t = mi.Float(dr.inf) if t is None else t
        self.seg = mi.UInt32(0) if seg is None else seg
        self.u = mi.Float(0) if u is None else u
        self.valid = mi.Bool(False) if valid is None else valid


class LatheGeometry(metaclass=_VariantStruct):
    """Local differential geometry at a hit: unit outward geometric normal
    ``n``, unit shading normal ``sh_n``, ``uv`` and the partials ``dp_du``,
    ``dp_dv``."""

    _FIELDS = {"n": "Vector3f", "sh_n": "Vector3f", "uv": "Point2f", "dp_du": "Vector3f", "dp_dv": "Vector3f"}

    def __init__(self, n=None, sh_n=None, uv=None, dp_du=None, dp_dv=None) -> None:
        self.n = mi.Vector3f(0, 0, 1) if n is None else n
        self.sh_n = mi.Vector3f(0, 0, 1) if sh_n is None else sh_n
        self.uv = mi.Point2f(0) if uv is None else uv
        self.dp_du = mi.Vector3f(0) if dp_du is None else dp_du
        self.dp_dv = mi.Vector3f(0) if dp_dv is None else dp_dv
