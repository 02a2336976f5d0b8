"""What the two edge-sampling terms of profile gradients share (the outline
term, silhouette.py, and the outline term seen through glass,
glass_outlines.py): numpy arrays handed to Dr.Jit in memory that keeps its
kernels cacheable, and the accumulation of edge samples into a gradient
image (forward mode) or into the parameters (reverse mode).

An edge sample is a pixel ``(row, column, inside)`` (numpy; ``inside``:
the pixel is on the film), a detached weight (numpy, (n, channels)) and an
attached scalar ``speed`` whose derivative, times the weight, is the
sample's share of the pixel's gradient (eqs. 26 and 42).
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

__all__ = ["add_edge_tangents", "backward_edge_terms", "jit_array", "numpy_array"]


def _aligned(values: np.ndarray, dtype) -> np.ndarray:
    """A contiguous copy of ``values`` whose memory starts on 64 bytes."""
    values = np.asarray(values, dtype=dtype)
    buffer = np.empty(values.nbytes + 64, dtype=np.uint8)
    start = -buffer.ctypes.data % 64
    out = buffer[start:start + values.nbytes].view(dtype).reshape(values.shape)
    out[...] = values
    return out


def jit_array(cls, values: np.ndarray):
    """``values`` (numpy, one row per component for vector types) as a
    Dr.Jit array of type ``cls``, from memory aligned on 64 bytes: Dr.Jit
    loads an array that wraps numpy memory with the alignment it happens to
    have, which is part of the compiled kernel (and of its cache key), so
    that every call would compile its kernels anew."""
    scalar = {mi.Float: np.float32, mi.UInt32: np.uint32, mi.Int32: np.int32, mi.Bool: bool}
    if cls in scalar:
        return cls(_aligned(values, scalar[cls]))
    return cls(*(mi.Float(_aligned(row, np.float32)) for row in np.asarray(values)))


def numpy_array(value, dtype=None) -> np.ndarray:
    """``value`` (a Dr.Jit array, of vectors: (n, components)) as numpy,
    evaluated first and copied component by component. ``np.array`` of an
    unevaluated vector array puts the components into one flat buffer at
    offsets of its width, written into the kernel as constants: as the edge
    samples' count changes from render to render, the kernel that computes
    the value (thousands of operations) compiled anew every time (about
    0.28 s per backward pass of the hollow glass on the CPU)."""
    dr.eval(value)
    if dr.depth_v(value) <= 1:
        return np.array(value, dtype=dtype)
    return np.stack([np.array(value[k], dtype=dtype) for k in range(len(value))], axis=-1)


def add_edge_tangents(image: np.ndarray, pixels: tuple, weight: np.ndarray, speed) -> None:
    """Forward mode: add the edge samples' weights times the tangent of
    ``speed`` (for the tangents set on the parameters) to their pixels of
    ``image`` (height, width, channels)."""
    if not dr.grad_enabled(speed):
        return
    row, column, inside = pixels
    tangent = np.array(dr.forward_to(speed, flags=dr.ADFlag.ClearEdges | dr.ADFlag.ClearInterior))
    channels = min(image.shape[2], weight.shape[1])
    np.add.at(image[..., :channels], (row[inside], column[inside]),
              weight[inside, :channels] * tangent[inside, None])


def backward_edge_terms(pixels: tuple, weight: np.ndarray, speed, grad_in: np.ndarray) -> None:
    """Reverse mode: accumulate the edge samples' part of the gradient of
    ``sum(grad_in * image)`` into the parameters ``speed`` depends on."""
    if not dr.grad_enabled(speed):
        return
    row, column, inside = pixels
    channels = min(weight.shape[1], grad_in.shape[2])
    adjoint = np.zeros(len(weight))
    adjoint[inside] = np.sum(grad_in[row[inside], column[inside], :channels] * weight[inside, :channels],
                             axis=1)
    dr.backward(dr.sum(speed * jit_array(mi.Float, adjoint)))
