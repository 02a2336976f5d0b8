"""Turntable animations: a lathe spinning about its own axis, or the camera
orbiting it, rendered frame by frame (the library behind ``lathe-turntable``).

Frame ``k`` of ``count`` shows the turn at ``360 * k / count`` degrees, so the
frames of a full turn loop seamlessly. Two modes:

* ``rotate`` -- the lathe spins in place: its new ``to_world`` is
  ``to_world @ rotate_z(angle)`` (a rotation about its local +z axis);
* ``orbit`` -- the first sensor moves about the lathe's world-space axis (the
  line through the ``to_world`` origin along the transformed local +z). The
  camera turns by ``-angle``, so for a rigid ``to_world`` the lathe is seen
  from the same sides, in the same order, as in ``rotate`` mode.

Every frame is a pure function of its index: the pose is computed from the
scene's original transforms (never accumulated) and the sampler seed is
``seed + index``, so frames can be rendered in any order, by any number of
processes, and re-rendering one gives the same image. It is bit-identical
(on the same kind of CPU) when the film's reconstruction filter is ``box``, or
with one Dr.Jit thread (``dr.set_thread_count(1)``); wider filters
(``gaussian``, Mitsuba's default) splat each sample into neighbouring pixels
with atomic adds whose order varies between threads, which changes a few
pixels by float32 rounding (at most about one half-float step in the EXR).
Frames are written to a temporary name and renamed, so an interrupted frame
never looks done.

Example::

    import mitsuba as mi
    mi.set_variant("llvm_ad_rgb")
    import lathe_shape
    from lathe_shape.tools.turntable import Turntable, plan_frames, write_frame

    scene = mi.load_file("scenes/wine_glass.xml", res=128)
    turntable = Turntable(scene, mode="rotate")
    os.makedirs("out", exist_ok=True)
    for frame in plan_frames(24, range(24), "out", seed=0):
        rgb = turntable.render(frame.angle_deg, spp=16, seed=frame.seed)
        write_frame(frame, rgb, {"angle_deg": frame.angle_deg, "seed": frame.seed})
"""

from __future__ import annotations

import math
import os
import re
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import mitsuba as mi
import numpy as np

from .images import read_exr, write_exr, write_png
from .scenes import integrator_name, scene_integrator

if TYPE_CHECKING:
    from ..plugin.shape import LatheShape

__all__ = [
    "JOB_KEYS",
    "MODES",
    "Frame",
    "Turntable",
    "TurntableError",
    "assemble_gif",
    "assemble_mp4",
    "frame_angle",
    "frame_pngs",
    "frame_state",
    "integrator_name",
    "lathe_axis",
    "orbit_matrix",
    "parse_frames",
    "plan_frames",
    "require_video",
    "rotate_z",
    "rotation_about_axis",
    "scene_lathes",
    "spin_matrix",
    "write_frame",
]

#: The two ways of turning: spin the lathe, or orbit the camera about it.
MODES = ("rotate", "orbit")

#: Header attributes a finished frame must match to be skipped on resume.
JOB_KEYS = ("count", "angle_deg", "mode", "object", "spp", "seed", "integrator")


class TurntableError(RuntimeError):
    """A turntable job cannot run; the message says why (no traceback needed)."""


# -- frame planning -----------------------------------------------------------


def frame_angle(index: int, count: int) -> float:
    """Angle of frame ``index`` of a full turn in ``count`` frames, in degrees."""
    return 360.0 * index / count


def parse_frames(text: str | None, count: int) -> range:
    """``--frames`` -> the half-open range of frame indices to render.

    ``"START:STOP"`` as in a Python slice (either end may be left out:
    ``":12"``, ``"12:"``), or a single index ``"K"`` (that frame only).
    ``STOP`` past the end is clipped to ``count``, so fixed-size shards such
    as ``0:10 10:20 20:30`` cover 24 frames. Negative indices, steps and empty
    ranges are errors (:class:`TurntableError`).
    """
    if count < 1:
        raise TurntableError(f"--count must be at least 1, got {count}")
    if text is None:
        return range(count)
    spec = text.strip()
    parts = spec.split(":")
    if len(parts) > 2:
        raise TurntableError(f"--frames expects START:STOP (no step), got {text!r}")
    try:
        values = [int(p) if p.strip() else None for p in parts]
    except ValueError:
        raise TurntableError(f"--frames expects integers START:STOP, e.g. 0:12, got {text!r}") from None
    if len(values) == 1:
        if values[0] is None:
            raise TurntableError(f"--frames expects START:STOP, e.g. 0:12, got {text!r}")
        start, stop = values[0], values[0] + 1
    else:
        start = 0 if values[0] is None else values[0]
        stop = count if values[1] is None else values[1]
    if start < 0 or stop < 0:
        raise TurntableError(f"--frames {text}: frame indices must not be negative")
    stop = min(stop, count)
    if start >= stop:
        raise TurntableError(
            f"--frames {text} selects no frame (the turn has frames 0 to {count - 1}; "
            "the range is half-open: START:STOP renders START to STOP-1)"
        )
    return range(start, stop)


@dataclass(frozen=True)
class Frame:
    """One frame of the turn: index, angle, sampler seed and output files."""

    index: int
    count: int
    angle_deg: float
    seed: int
    exr: str
    png: str


def frame_stem(index: int, count: int) -> str:
    """``frame_0007``: four digits, more when the turn needs them."""
    digits = max(4, len(str(count - 1)))
    return f"frame_{index:0{digits}d}"


def plan_frames(count: int, frames: Sequence[int], out_dir: str | os.PathLike, seed: int = 0) -> list[Frame]:
    """The :class:`Frame` list for ``frames`` (indices) of a ``count``-frame
    turn written to ``out_dir``; frame ``k`` is sampled with seed ``seed + k``."""
    out_dir = os.fspath(out_dir)
    plan = []
    for index in frames:
        stem = os.path.join(out_dir, frame_stem(index, count))
        angle = frame_angle(index, count)
        plan.append(Frame(index, count, angle, seed + index, stem + ".exr", stem + ".png"))
    return plan


def frame_state(
    frame: Frame, expect: dict[str, object] | None = None, size: tuple[int, int] | None = None
) -> str:
    """Is ``frame`` already on disk? ``"missing"`` (no complete EXR + PNG
    pair, or an unreadable EXR), ``"stale"`` (a readable frame of another
    job: a header attribute differs from ``expect``, or the image from
    ``size`` = (width, height)) or ``"done"``."""
    if not (os.path.isfile(frame.exr) and os.path.isfile(frame.png)):
        return "missing"
    try:
        pixels, header = read_exr(frame.exr)
    except Exception:  # truncated or foreign file: render it again
        return "missing"
    if size is not None and tuple(pixels.shape[:2]) != (size[1], size[0]):
        return "stale"
    for key, value in (expect or {}).items():
        if key not in header or not _same(header[key], value):
            return "stale"
    return "done"


def _same(stored: object, value: object) -> bool:
    if isinstance(value, float):
        try:
            return math.isclose(float(stored), value, rel_tol=1e-6, abs_tol=1e-9)
        except (TypeError, ValueError):
            return False
    return stored == value


# -- transforms ---------------------------------------------------------------


def _cos_sin(angle_deg: float) -> tuple[float, float]:
    """cos and sin of an angle in degrees, exact at multiples of 90 degrees
    (so e.g. the frames of a 4-frame turn carry no round-off: cos(pi/2) is
    6e-17, not 0)."""
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
    """World-space axis of a lathe: (origin, unit direction) of its local +z."""
    to_world = np.asarray(to_world, dtype=np.float64)
    direction = to_world[:3, 2]
    length = np.linalg.norm(direction)
    if not length > 0.0:
        raise TurntableError("the lathe's to_world collapses its axis (local +z maps to zero)")
    return to_world[:3, 3].copy(), direction / length


def spin_matrix(to_world: np.ndarray, angle_deg: float) -> np.ndarray:
    """``rotate`` mode: the lathe turned by ``angle_deg`` about its own axis."""
    return np.asarray(to_world, dtype=np.float64) @ rotate_z(angle_deg)


def orbit_matrix(
    sensor_to_world: np.ndarray, object_to_world: np.ndarray | None, angle_deg: float
) -> np.ndarray:
    """``orbit`` mode: the sensor moved by ``-angle_deg`` about the object's
    axis (the world z axis through the origin when ``object_to_world`` is
    None), so the object appears to turn by ``+angle_deg``."""
    if object_to_world is None:
        origin, axis = np.zeros(3), np.array([0.0, 0.0, 1.0])
    else:
        origin, axis = lathe_axis(object_to_world)
    return rotation_about_axis(origin, axis, -angle_deg) @ np.asarray(sensor_to_world, dtype=np.float64)


# -- the scene ----------------------------------------------------------------


def lathe_ids_in_file(path: str | os.PathLike) -> list[str]:
    """Ids of the ``<shape type="lathe">`` elements of an XML file in
    document order (``""`` for one without id; empty if the file cannot be
    parsed)."""
    try:
        root = ET.parse(os.fspath(path)).getroot()
    except (OSError, ET.ParseError):
        return []
    return [e.get("id", "") for e in root.iter("shape") if e.get("type") == "lathe"]


def scene_lathes(scene: mi.Scene, path: str | os.PathLike | None = None) -> list[LatheShape]:
    """The scene's lathes, in the order of the XML file ``path`` when given
    (``scene.shapes()`` keeps no particular order). Lathes are matched to the
    file's elements by id; those without id take the places of the file's
    elements without id."""
    # Imported here: the plugin class needs a Mitsuba variant to be set.
    from ..plugin.shape import LatheShape

    lathes = [s for s in scene.shapes() if isinstance(s, LatheShape)]
    if path is None:
        return lathes
    names = lathe_ids_in_file(path)
    rank: dict[str, int] = {}
    for i, name in enumerate(names):
        rank.setdefault(name, i)
    anonymous = iter([i for i, name in enumerate(names) if not name])
    keys = [rank.get(s.id(), len(names)) if s.id() else next(anonymous, len(names)) for s in lathes]
    return [s for _, s in sorted(zip(keys, lathes, strict=True), key=lambda pair: pair[0])]


def _describe_ids(lathes: Sequence[LatheShape]) -> str:
    return ", ".join(f"'{s.id()}'" if s.id() else "(a lathe without id)" for s in lathes) or "none"


def _keys_of(params: mi.SceneParameters, node: mi.Object, suffix: str) -> list[str]:
    """Keys of ``mi.traverse(scene)`` naming a parameter ``suffix`` of the
    object ``node`` itself (not of its children)."""
    return [k for k in params.keys() if k.split(".")[-1] == suffix and params.properties[k][2] is node]


def _matrix(transform: object) -> np.ndarray:
    """A Mitsuba (JIT or scalar) transform -> (4, 4) float64."""
    m = np.array(transform.matrix, dtype=np.float64)
    return m.reshape(4, 4) if m.size == 16 else m[..., 0]


class Turntable:
    """Poses a scene for any angle of the turn and renders it.

    ``mode`` is ``"rotate"`` (spin the lathe ``object``) or ``"orbit"`` (move
    the first sensor about the lathe's axis). ``object_id`` names the lathe;
    ``None`` picks the first lathe (in the order of the XML file
    ``scene_path`` when given). The original transforms are kept, so
    :meth:`pose` is absolute: ``pose(a)`` gives the same scene whatever was
    posed before.
    """

    def __init__(
        self,
        scene: mi.Scene,
        mode: str = "rotate",
        object_id: str | None = None,
        scene_path: str | os.PathLike | None = None,
    ) -> None:
        if mode not in MODES:
            raise TurntableError(f"unknown turntable mode '{mode}' (expected one of: {', '.join(MODES)})")
        self.scene = scene
        self.mode = mode
        #: The scene's integrator (stock ``path`` when it names none).
        self.integrator = scene_integrator(scene)
        lathes = scene_lathes(scene, scene_path)
        #: The lathe that turns (rotate) or whose axis the camera orbits.
        self.lathe: LatheShape | None = None
        if object_id is not None:
            matches = [s for s in lathes if s.id() == object_id]
            if not matches:
                raise TurntableError(
                    f"the scene has no lathe with id '{object_id}' "
                    f"(lathes in the scene: {_describe_ids(lathes)})"
                )
            self.lathe = matches[0]
        elif lathes:
            self.lathe = lathes[0]
        elif mode == "rotate":
            raise TurntableError("the scene has no lathe shape to rotate (use --orbit to orbit the camera)")
        #: All lathes of the scene, in file order.
        self.lathes = lathes
        self.lathe_to_world = None if self.lathe is None else self.lathe.to_world_matrix.copy()

        if not scene.sensors():
            raise TurntableError("the scene has no sensor")
        self.sensor = scene.sensors()[0]
        self._sensor_key = None
        if mode == "orbit":
            params = mi.traverse(scene)
            keys = _keys_of(params, self.sensor, "to_world")
            if not keys:
                raise TurntableError(f"the sensor '{self.sensor.class_name()}' has no to_world to orbit")
            self._sensor_key = min(keys, key=len)
            self.sensor_to_world = _matrix(params[self._sensor_key])
        self._angle: float | None = None

    @property
    def object_id(self) -> str:
        """Id of the turning (or orbited) lathe; ``""`` when there is none."""
        return "" if self.lathe is None else self.lathe.id()

    def pose(self, angle_deg: float) -> None:
        """Pose the scene at ``angle_deg`` of the turn."""
        if self._angle is not None and self._angle == angle_deg:
            return
        if self.mode == "rotate":
            self._move_lathe(spin_matrix(self.lathe_to_world, angle_deg))
        else:
            matrix = orbit_matrix(self.sensor_to_world, self.lathe_to_world, angle_deg)
            params = mi.traverse(self.scene)
            params[self._sensor_key] = mi.AffineTransform4f(matrix.astype(np.float32))
            params.update()
        self._angle = angle_deg

    def _move_lathe(self, matrix: np.ndarray) -> None:
        self.lathe.set_to_world(matrix, self.scene)

    def render(self, angle_deg: float, spp: int | None = None, seed: int = 0) -> np.ndarray:
        """Pose the scene at ``angle_deg`` and render it with the first
        sensor (``spp`` None: the sensor's sampler count): (H, W, 3) linear
        RGB float32."""
        self.pose(angle_deg)
        image = mi.render(self.scene, spp=spp or 0, seed=seed, sensor=self.sensor,
                          integrator=self.integrator)
        return np.asarray(image.numpy(), dtype=np.float32)[..., :3]


# -- output -------------------------------------------------------------------


def _temporary(path: str) -> str:
    """A hidden name beside ``path`` with the same extension (Mitsuba picks
    the image format from it), unique to this process."""
    folder, name = os.path.split(path)
    stem, ext = os.path.splitext(name)
    return os.path.join(folder, f".{stem}.{os.getpid()}.tmp{ext}")


def write_frame(frame: Frame, rgb: np.ndarray, metadata: dict[str, object]) -> None:
    """Write a frame's half-float EXR (with ``metadata``) and sRGB PNG
    atomically: both go to temporary names in the output folder and are
    renamed when complete, the EXR last."""
    tmp_exr, tmp_png = _temporary(frame.exr), _temporary(frame.png)
    try:
        write_png(tmp_png, rgb)
        write_exr(tmp_exr, rgb, metadata, half=True)
        os.replace(tmp_png, frame.png)
        os.replace(tmp_exr, frame.exr)
    finally:
        for tmp in (tmp_exr, tmp_png):
            if os.path.exists(tmp):
                os.remove(tmp)


def frame_pngs(out_dir: str | os.PathLike, count: int) -> list[str]:
    """PNGs of all frames of a ``count``-frame turn present in ``out_dir``,
    in frame order."""
    out_dir = os.fspath(out_dir)
    pattern = re.compile(r"frame_(\d+)\.png")
    found = []
    for name in os.listdir(out_dir):
        match = pattern.fullmatch(name)
        if match and int(match.group(1)) < count and name == frame_stem(int(match.group(1)), count) + ".png":
            found.append((int(match.group(1)), os.path.join(out_dir, name)))
    return [path for _, path in sorted(found)]


def _read_pngs(pngs: Sequence[str]) -> list[np.ndarray]:
    rgb8 = (mi.Bitmap.PixelFormat.RGB, mi.Struct.Type.UInt8, True)
    images = [np.asarray(mi.Bitmap(p).convert(*rgb8)) for p in pngs]
    shapes = {im.shape for im in images}
    if len(shapes) > 1:
        raise TurntableError(
            "the frames have different sizes (" + ", ".join(f"{s[1]}x{s[0]}" for s in sorted(shapes))
            + "); render them all with the same --resolution"
        )
    return images


def _video_import_error(what: str, e: ImportError) -> TurntableError:
    return TurntableError(
        f"{what} needs the optional video dependencies (missing: {e.name or e}): "
        "pip install lathe_shape[video]"
    )


def require_video(gif: bool = False, mp4: bool = False) -> None:
    """Check up front (before hours of rendering) that the packages for the
    requested animations import."""
    try:
        if gif:
            import imageio.v3  # noqa: F401
            import PIL  # noqa: F401
    except ImportError as e:
        raise _video_import_error("--gif", e) from None
    try:
        if mp4:
            import imageio_ffmpeg  # noqa: F401
    except ImportError as e:
        raise _video_import_error("--mp4", e) from None


def assemble_gif(pngs: Sequence[str], path: str | os.PathLike, fps: float) -> None:
    """Animated, looping GIF of the PNG frames (imageio + pillow)."""
    try:
        import imageio.v3 as iio
        import PIL  # noqa: F401  (imageio's GIF writer)
    except ImportError as e:
        raise _video_import_error("--gif", e) from None
    if not pngs:
        raise TurntableError("no frames to put in the GIF")
    images = _read_pngs(pngs)
    path = os.fspath(path)
    tmp = _temporary(path)
    try:
        # Pillow's GIF durations are whole milliseconds.
        iio.imwrite(tmp, np.stack(images), extension=".gif", plugin="pillow",
                    duration=int(round(1000.0 / fps)), loop=0)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


def assemble_mp4(pngs: Sequence[str], path: str | os.PathLike, fps: float) -> None:
    """H.264 MP4 of the PNG frames (imageio-ffmpeg); odd sizes are padded by
    one pixel, as yuv420p needs even ones."""
    try:
        import imageio_ffmpeg
    except ImportError as e:
        raise _video_import_error("--mp4", e) from None
    if not pngs:
        raise TurntableError("no frames to put in the MP4")
    images = _read_pngs(pngs)
    height, width = images[0].shape[:2]
    pad = ((0, height % 2), (0, width % 2), (0, 0))
    path = os.fspath(path)
    tmp = _temporary(path)
    try:
        writer = imageio_ffmpeg.write_frames(
            tmp, (width + width % 2, height + height % 2), fps=fps, codec="libx264",
            pix_fmt_in="rgb24", pix_fmt_out="yuv420p", macro_block_size=1, quality=8,
            ffmpeg_log_level="error",
        )
        writer.send(None)  # start ffmpeg
        try:
            for image in images:
                writer.send(np.ascontiguousarray(np.pad(image, pad, mode="edge")))
        finally:
            writer.close()
        os.replace(tmp, path)
    except (OSError, RuntimeError) as e:
        raise TurntableError(f"ffmpeg could not write '{path}': {e}") from None
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)
