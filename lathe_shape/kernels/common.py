"""Result types shared by the intersection kernels.

Both kernels report a hit as ``(t, seg, u, valid)`` and the local geometry at
a hit as ``(n, sh_n, uv, dp_du, dp_dv)``. The classes are Dr.Jit structs
(usable with ``dr.select``, ``dr.zeros`` and as loop state) whose field types
come from the active Mitsuba variant, so the kernels can be imported before
``mi.set_variant``.
"""

from __future__ import annotations

from collections.abc import Callable

import drjit as dr
import mitsuba as mi
import numpy as np

__all__ = ["LEAF", "LatheHit", "LatheGeometry", "threaded_bvh"]

#: Flag bit in a threaded-BVH link word marking a leaf (low bits: its index).
LEAF = 0x80000000


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


def _median_split(box: np.ndarray, idx: np.ndarray):
    """Median-split tree over the boxes ``idx`` of ``box`` (rows ``(rmin,
    rmax, zmin, zmax)``): ``('leaf', k, bounds)`` or ``('node', bounds, axis,
    lower, upper)``, ``lower`` holding the smaller centres along ``axis``
    (0: r, 1: z), the axis along which the centres spread most."""
    bounds = (box[idx, 0].min(), box[idx, 1].max(), box[idx, 2].min(), box[idx, 3].max())
    if len(idx) == 1:
        return ("leaf", int(idx[0]), bounds)
    cr = 0.5 * (box[idx, 0] + box[idx, 1])
    cz = 0.5 * (box[idx, 2] + box[idx, 3])
    axis = 0 if np.ptp(cr) > np.ptp(cz) else 1
    order = idx[np.argsort(cr if axis == 0 else cz, kind="stable")]
    half = len(order) // 2
    return ("node", bounds, axis, _median_split(box, order[:half]), _median_split(box, order[half:]))


def threaded_bvh(
    box: np.ndarray,
    inner_record: Callable[[tuple], list],
    leaf_record: Callable[[int, tuple], list],
) -> tuple[list, list, int]:
    """A stackless BVH over annular boxes in the (r, z) plane.

    ``box`` is (n, 4) with rows ``(rmin, rmax, zmin, zmax)``. The median-split
    tree is stored four times in pre-order with miss links, so that a ray can
    walk it with one index: copy ``2 * (d_z < 0) + (moving away from the
    axis)`` visits the lower child of a z split first when the ray goes up,
    and the outer child of an r split first when it moves outward.

    Returns ``(records, links, n_nodes)``: ``records[k]`` is
    ``inner_record(bounds)`` or ``leaf_record(index, bounds)``; ``links[k]``
    is an inner node's miss link (global index of the next node after its
    subtree) or ``LEAF | index`` for a leaf; ``n_nodes`` per copy.
    """
    tree = _median_split(np.asarray(box, dtype=np.float64), np.arange(len(box)))
    records: list = []
    links: list = []

    def thread(node, z_up: bool, r_out: bool) -> None:
        if node[0] == "leaf":
            records.append(leaf_record(node[1], node[2]))
            links.append(LEAF | node[1])
            return
        _, bounds, axis, first, second = node
        if (axis == 1 and not z_up) or (axis == 0 and r_out):
            first, second = second, first
        me = len(records)
        records.append(inner_record(bounds))
        links.append(0)
        thread(first, z_up, r_out)
        thread(second, z_up, r_out)
        links[me] = len(records)  # miss link: next node after this subtree

    for z_up, r_out in [(True, True), (True, False), (False, True), (False, False)]:
        thread(tree, z_up, r_out)
    n_nodes = 2 * len(box) - 1
    assert len(records) == 4 * n_nodes
    return records, links, n_nodes
