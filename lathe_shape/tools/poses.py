"""The poses of a turntable: 4x4 rigid transforms (float64 NumPy) that spin a
lathe about its own axis, move a camera about it, or turn the rest of the
world about it.

A lathe's axis is its local +z: in world space, the line through the
``to_world`` origin along the transformed +z. Spinning the lathe by ``a``
and orbiting the camera by ``-a`` about that axis show the lathe from the
same side (exactly so for a rigid ``to_world``). Turning the world (every
emitter and every other shape) by ``-a`` about the axis turns the lathe by
``a`` against its surroundings, as spinning it does, while the camera keeps
its view of the lathe.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = [
    "DEFAULT_MODE",
    "MODES",
    "MODE_ALIASES",
    "lathe_axis", "orbit_matrix", "rotate_z", "rotation_about_axis", "spin_matrix",
    "world_matrix",
]

#: The ways of turning: orbit the camera, turn the world, spin the lathe.
MODES = ("orbit", "world", "spin")
#: Other names accepted for a mode.
MODE_ALIASES = {"rotate": "spin"}
#: The mode of a turntable that names none.
DEFAULT_MODE = "orbit"


def _cos_sin(angle_deg: float) -> tuple[float, float]:
    """cos and sin of an angle in degrees, exact at multiples of 90 degrees
    (so e.g. the frames of a 4-frame turn carry no round-off: cos(pi/2) is
    6e-17, not 0). A ``ValueError`` for an angle that is not finite."""
    if not math.isfinite(angle_deg):
        raise ValueError(f"a turntable angle must be a finite number of degrees, got {angle_deg!r}")
    quarter = angle_deg / 90.0
    if quarter == round(quarter):
        return [(1.0, 0.0), (0.0, 1.0), (-1.0, 0.0), (0.0, -1.0)][int(round(quarter)) % 4]
    a = math.radians(angle_deg)
    return math.cos(a), math.sin(a)


def rotate_z(angle_deg: float) -> np.ndarray:
    """4x4 rotation by ``angle_deg`` about +z (counter-clockwise seen from +z)."""
    c, s = _cos_sin(angle_deg)
    m = np.eye(4)
    m[:2, :2] = [[c, -s], [s, c]]
    return m


def rotation_about_axis(origin: np.ndarray, axis: np.ndarray, angle_deg: float) -> np.ndarray:
    """4x4 rotation by ``angle_deg`` about the line through ``origin`` along
    ``axis`` (right-handed: counter-clockwise seen from the tip of ``axis``)."""
    origin = np.asarray(origin, dtype=np.float64)
    axis = np.asarray(axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis)
    c, s = _cos_sin(angle_deg)
    # Rodrigues' formula; exactly the identity at 0 degrees.
    cross = np.array([[0.0, -axis[2], axis[1]], [axis[2], 0.0, -axis[0]], [-axis[1], axis[0], 0.0]])
    linear = c * np.eye(3) + s * cross + (1.0 - c) * np.outer(axis, axis)
    m = np.eye(4)
    m[:3, :3] = linear
    m[:3, 3] = origin - linear @ origin
    return m


def lathe_axis(to_world: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World-space axis of a lathe: (origin, unit direction) of its local +z.
    Raises ValueError when ``to_world`` collapses the axis."""
    to_world = np.asarray(to_world, dtype=np.float64)
    direction = to_world[:3, 2]
    length = np.linalg.norm(direction)
    if not length > 0.0:
        raise ValueError("the lathe's to_world collapses its axis (local +z maps to zero)")
    return to_world[:3, 3].copy(), direction / length


def spin_matrix(to_world: np.ndarray, angle_deg: float) -> np.ndarray:
    """The lathe's ``to_world`` turned by ``angle_deg`` about its own axis:
    ``to_world @ rotate_z(angle)``."""
    return np.asarray(to_world, dtype=np.float64) @ rotate_z(angle_deg)


def orbit_matrix(
    sensor_to_world: np.ndarray, object_to_world: np.ndarray | None, angle_deg: float
) -> np.ndarray:
    """The sensor's ``to_world`` moved by ``-angle_deg`` about the object's
    axis (the world z axis through the origin when ``object_to_world`` is
    None), so the object appears to turn by ``+angle_deg``."""
    return world_matrix(object_to_world, angle_deg) @ np.asarray(sensor_to_world, dtype=np.float64)


def world_matrix(object_to_world: np.ndarray | None, angle_deg: float) -> np.ndarray:
    """The rotation applied to the rest of the world (emitters, other shapes)
    in ``world`` mode: ``-angle_deg`` about the object's axis (the world z
    axis through the origin when ``object_to_world`` is None), so the object
    turns by ``+angle_deg`` against its surroundings."""
    if object_to_world is None:
        origin, axis = np.zeros(3), np.array([0.0, 0.0, 1.0])
    else:
        origin, axis = lathe_axis(object_to_world)
    return rotation_about_axis(origin, axis, -angle_deg)
