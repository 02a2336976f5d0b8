"""The silhouette term of profile gradients: edge sampling of a lathe's
exact, analytic silhouette as seen by the camera (primary visibility).

Attached hits (attached_hits.py) give the derivative of what each camera ray
sees while it keeps seeing the same surface. Where the lathe's outline moves
across a pixel, the pixel also gains the radiance on one side of the outline
and loses the other's (docs/method.md, eq. 26):

    dI_p = sum over outline pieces in pixel p of (f_in - f_out) (n . dx) dl,

``x`` the outline's image position (pixels), ``n`` its unit image normal
and ``dl`` the piece's image length. The outline of a lathe is known in
closed form for a pinhole at ``c`` (local frame, eq. 27): a profile point
``(R, Z)`` with outward normal ``(n_r, n_z)`` lies on it at the azimuths

    phi = phi_c +- acos((n_r R + n_z (Z - c_z)) / (n_r rho_c)),

``rho_c, phi_c`` the camera's polar coordinates; on a polyline segment the
argument is constant (a cone's outline is two generators), on a B-spline it
varies along the curve. A polyline's joint circles are outline too where
the two adjacent cones face the camera differently, and so is a crease of
the shading normal that the camera sees (eq. 10's sharp joints: the
radiance jumps across it, and it moves with its joint point). The outline
pieces are material points ``(segment, u, phi)``, placed detached; their
positions are attached to the profile points, and a tangential slide of a
material point along the outline does not change ``n . dx``, so the
point's own motion gives the outline's. ``f_in - f_out`` is estimated with camera rays just
either side of the outline (an outline hidden behind other surfaces gets
zero difference), traced with the integrator's primal ``sample``.
Outlines seen through glass are glass_outlines.py's; shadow boundaries are
not included.
"""

from __future__ import annotations

import drjit as dr
import mitsuba as mi
import numpy as np

from ..kernels.attached import profile_point
from ..profiles import bspline as bs
from ..surfaces import kind_of
from .attached_hits import differentiable_lathes
from .edge_terms import add_edge_tangents, backward_edge_terms, jit_array, numpy_array
from .shape import LatheShape

__all__ = ["OutlineSamples", "outline_backward", "outline_forward", "outline_radiance_difference",
           "outline_samples"]

#: Offset of the two rays either side of the outline, in pixels: rays much
#: closer graze the surface, and the kernel reports no hit for a ray that
#: grazes a joint (kernels/polyline.py); 0.02 lost a quarter of the outline.
_EPSILON = 0.1

#: The side rays' offset at a crease seen from the front of both cones
#: (no grazing there): close, so that near the crease's ends, where it
#: meets an outline tangentially, the rays stay on the lathe.
_CREASE_EPSILON = 0.01

#: Outline samples per pixel of image length (at least 4 per piece).
_DENSITY = 2.0


class OutlineSamples:
    """Outline pieces of the lathes in one view: material points ``seg``,
    ``u``, ``phi`` and owner ``lathe`` (numpy), the detached image normal
    ``normal`` times the image length ``dl`` (numpy, (n, 2)), image
    position ``x`` (numpy, (n, 2), pixels) and the side rays' offset
    (numpy, (n,), pixels)."""

    def __init__(self) -> None:
        self.parts: list[tuple[LatheShape, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray,
                               np.ndarray]] = []

    def add(self, lathe, seg, u, phi, normal_dl, x, offset: float | np.ndarray | None = None) -> None:
        """Pieces, with the side rays' ``offset`` (pixels, default
        :data:`_EPSILON`)."""
        if len(seg):
            offset = np.broadcast_to(_EPSILON if offset is None else offset, (len(seg),))
            self.parts.append((lathe, seg, u, phi, normal_dl, x, offset))

    def merged(self) -> list[tuple]:
        """The parts concatenated per lathe (in the order first added)."""
        lathes = list(dict.fromkeys(part[0] for part in self.parts))
        return [(lathe, *(np.concatenate([part[k] for part in self.parts if part[0] is lathe])
                          for k in range(1, 7))) for lathe in lathes]


def _project(sensor: mi.Sensor, points: np.ndarray) -> np.ndarray:
    """Image positions (pixels) of world points (n, 3)."""
    it = dr.zeros(mi.Interaction3f, len(points))
    it.p = jit_array(mi.Point3f, np.asarray(points).T)
    ds, _ = sensor.sample_direction(it, mi.Point2f(0.5))
    return numpy_array(ds.uv, np.float64)


def _world(lathe: LatheShape, r, z, phi) -> np.ndarray:
    """World points of local cylindrical coordinates."""
    m = lathe.to_world_matrix
    local = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=1)
    return local @ m[:3, :3].T + m[:3, 3]


def _curve_numpy(lathe: LatheShape, seg: np.ndarray, u: np.ndarray):
    """``(R, Z, n_r, n_z)`` of the canonical profile at ``(seg, u)``."""
    if kind_of(lathe.surface).kernel == "bspline":
        controls = lathe.profile.segment_controls
        r, z = bs.evaluate(controls, seg, u)
        dr_, dz_ = bs.derivative(controls, seg, u)
    else:
        p0, p1 = lathe.profile.segment_points()
        r = p0[seg, 0] + u * (p1[seg, 0] - p0[seg, 0])
        z = p0[seg, 1] + u * (p1[seg, 1] - p0[seg, 1])
        dr_, dz_ = p1[seg, 0] - p0[seg, 0], p1[seg, 1] - p0[seg, 1]
    length = np.maximum(np.hypot(dr_, dz_), 1e-300)
    return r, z, -dz_ / length, dr_ / length


def _outline_azimuth(r, z, n_r, n_z, camera: np.ndarray, branch: float, clip: bool = False):
    """Eq. 27: azimuth of the outline at profile points (NaN where none;
    with ``clip``, the nearest azimuth where the argument leaves [-1, 1])."""
    rho_c = np.hypot(camera[0], camera[1])
    phi_c = np.arctan2(camera[1], camera[0])
    with np.errstate(divide="ignore", invalid="ignore"):
        kappa = (n_r * r + n_z * (z - camera[2])) / (n_r * rho_c)
        kappa = np.clip(kappa, -1.0, 1.0) if clip else np.where(np.abs(kappa) < 1.0, kappa, np.nan)
        return phi_c + branch * np.arccos(kappa)


def _add_pieces(out: OutlineSamples, sensor, lathe, seg, u_lo, u_hi, branch, camera) -> None:
    """Outline pieces between the material points ``(seg, u_lo, phi(u_lo))``
    and ``(seg, u_hi, phi(u_hi))`` of the outline branches ``branch`` (+-1);
    the sample is the middle one. A piece whose middle is on the outline
    keeps its ends (where the outline ends inside the piece, at its nearest
    azimuth). One projection for all pieces."""
    points, azimuths = [], []
    for u, clip in ((u_mid := 0.5 * (u_lo + u_hi), False), (u_lo, True), (u_hi, True)):
        r, z, n_r, n_z = _curve_numpy(lathe, seg, u)
        phi = _outline_azimuth(r, z, n_r, n_z, camera, branch, clip)
        points.append(_world(lathe, r, z, np.nan_to_num(phi)))
        azimuths.append(phi)
    ok = np.isfinite(azimuths[0])
    if not ok.any():
        return
    x_mid, x_lo, x_hi = np.split(_project(sensor, np.concatenate([p[ok] for p in points])), 3)
    step = x_hi - x_lo
    normal_dl = np.stack([-step[:, 1], step[:, 0]], axis=1)  # |n| dl = |step|
    out.add(lathe, seg[ok], u_mid[ok], azimuths[0][ok], normal_dl, x_mid)


def _segment_outlines(out: OutlineSamples, sensor, lathe, camera, size: float) -> None:
    """The outline along every profile segment (both branches), with about
    ``_DENSITY`` pieces per pixel of its image length."""
    n_seg = lathe.profile.segment_count
    coarse = np.linspace(0.0, 1.0, 33)
    seg = np.repeat(np.arange(n_seg), len(coarse))
    u = np.tile(coarse, n_seg)
    r, z, n_r, n_z = _curve_numpy(lathe, seg, u)
    pieces = []
    for branch in (1.0, -1.0):
        # n_r = 0 (an annulus) has no outline: NaN, counted as no length
        phi = _outline_azimuth(r, z, n_r, n_z, camera, branch, True)
        x = _project(sensor, _world(lathe, r, z, np.nan_to_num(phi))).reshape(n_seg, len(coarse), 2)
        length = np.nan_to_num(np.linalg.norm(np.diff(x, axis=1), axis=2)
                               * np.isfinite(phi.reshape(n_seg, -1))[:, 1:]).sum(axis=1)
        for k in np.flatnonzero(length > 0):
            count = int(np.clip(np.ceil(_DENSITY * length[k]), 8, 4096))
            edges = np.linspace(0.0, 1.0, count + 1)
            pieces.append((np.full(count, k), edges[:-1], edges[1:], np.full(count, branch)))
    if pieces:
        seg, u_lo, u_hi, branch = (np.concatenate(column) for column in zip(*pieces, strict=True))
        _add_pieces(out, sensor, lathe, seg, u_lo, u_hi, branch, camera)


def _facing_arcs(r: float, z: float, normals: list[np.ndarray], camera: np.ndarray,
                 creased: bool = False) -> list[tuple[float, float, bool]]:
    """Azimuth intervals of the joint circle ``(r, z)`` where the two cones
    of ``normals`` face the camera differently (an outline), and where the
    joint is a shading crease (``creased``) also those where both face it
    (a crease seen directly: the shading normal, hence the radiance, jumps
    across it): between consecutive roots of eq. 27 for either cone (the
    ends of their outline generators), each with whether it is a crease."""
    roots = [0.0, 2 * np.pi]
    for n in normals:
        for branch in (1.0, -1.0):
            phi = _outline_azimuth(np.array([r]), np.array([z]), n[0], n[1], camera, branch)[0]
            if np.isfinite(phi):
                roots.append(float(np.mod(phi, 2 * np.pi)))
    roots = sorted(roots)
    arcs = []
    for lo, hi in zip(roots[:-1], roots[1:], strict=True):
        mid = 0.5 * (lo + hi)
        to_camera = camera - np.array([r * np.cos(mid), r * np.sin(mid), z])
        sides = [np.dot([n[0] * np.cos(mid), n[0] * np.sin(mid), n[1]], to_camera) > 0 for n in normals]
        if hi > lo and (sides[0] != sides[1] or (creased and sides[0] and sides[1])):
            arcs.append((lo, hi, sides[0] == sides[1]))
    return arcs


def _joint_outlines(out: OutlineSamples, sensor, lathe, camera, size: float) -> None:
    """Polylines: the arcs of the joint circles between two cones that face
    the camera differently (one front-, one back-facing), and of the
    creases (where the interpolated shading normal jumps, eq. 10, or
    everywhere on a lathe shaded flat) that the camera sees from the front
    of both cones. One projection for all arcs."""
    profile = lathe.profile
    _, p1 = profile.segment_points()
    normals = profile.segment_normals()
    m = profile.segment_count
    arcs = []  # (segment, r, z, lower edges, upper edges) of every arc
    for k in range(m):
        j = (k + 1) % m
        if profile.segments[k, 1] != profile.segments[j, 0] or (j == 0 and not profile.closed_loop):
            continue
        r, z = p1[k]
        if r <= 0.0:
            continue
        creased = not lathe.smooth or not np.allclose(profile.normal_end[k], profile.normal_start[j],
                                                      atol=1e-9)
        for lo, hi, crease in _facing_arcs(r, z, [normals[k], normals[j]], camera, creased):
            count = int(np.clip(np.ceil(_DENSITY * (hi - lo) * r * size), 2, 8192))
            edges = np.linspace(lo, hi, count + 1)
            arcs.append((np.full(count, k), np.full(count, r), np.full(count, z), edges[:-1], edges[1:],
                         np.full(count, _CREASE_EPSILON if crease else _EPSILON)))
    if not arcs:
        return
    seg, r, z, lo, hi, offset = (np.concatenate(column) for column in zip(*arcs, strict=True))
    phi = 0.5 * (lo + hi)
    world = np.concatenate([_world(lathe, r, z, azimuth) for azimuth in (lo, hi, phi)])
    x_lo, x_hi, x_mid = np.split(_project(sensor, world), 3)
    step = x_hi - x_lo
    normal_dl = np.stack([-step[:, 1], step[:, 0]], axis=1)
    out.add(lathe, seg, np.ones(len(seg)), phi, normal_dl, x_mid, offset)


def outline_samples(sensor: mi.Sensor, lathes: list[LatheShape]) -> OutlineSamples:
    """The outline pieces of ``lathes`` seen by the perspective ``sensor``."""
    out = OutlineSamples()
    origin = np.array(sensor.world_transform() @ mi.ScalarPoint3f(0.0), dtype=np.float64).ravel()
    width, height = sensor.film().crop_size()
    for lathe in lathes:
        camera = np.linalg.inv(lathe.to_world_matrix) @ np.append(origin, 1.0)
        # Pixels per unit of length near the lathe (for the sample counts)
        center = lathe.to_world_matrix[:3, 3]
        size = max(width, height) / max(np.linalg.norm(origin - center), 1e-6)
        _segment_outlines(out, sensor, lathe, camera[:3], size)
        if kind_of(lathe.surface).kernel == "polyline":
            _joint_outlines(out, sensor, lathe, camera[:3], size)
    return out


def attached_outline_positions(sensor: mi.Sensor, lathe: LatheShape, seg, u,
                               phi) -> tuple[mi.Point2f, mi.Point3f]:
    """Image positions and world points of the material points, attached to
    the profile."""
    r, z = profile_point(lathe.profile_points, lathe.profile_index, kind_of(lathe.surface).kernel,
                         jit_array(mi.UInt32, seg), jit_array(mi.Float, u))
    phi = jit_array(mi.Float, phi)
    local = mi.Point3f(r * dr.cos(phi), r * dr.sin(phi), z)
    it = dr.zeros(mi.Interaction3f, len(seg))
    it.p = lathe._to_world @ local
    ds, _ = sensor.sample_direction(it, mi.Point2f(0.5))
    return ds.uv, it.p


def _unit(normal_dl: np.ndarray) -> np.ndarray:
    """The unit image normals of the pieces ``normal_dl`` (n, 2)."""
    return normal_dl / np.maximum(np.linalg.norm(normal_dl, axis=1, keepdims=True), 1e-30)


def _side_radiance(scene: mi.Scene, sensor: mi.Sensor, integrator, x: np.ndarray, normal_dl: np.ndarray,
                   seed: int, spp: int, epsilon: np.ndarray | float = _EPSILON) -> mi.Spectrum:
    """The integrator's primal radiance (times the sensor weight, not yet
    evaluated) of camera rays at ``x - eps n`` and ``x + eps n``, ``spp``
    rounds of both."""
    width, height = sensor.film().crop_size()
    offset = np.reshape(epsilon, (-1, 1)) * _unit(normal_dl)
    positions = np.tile(np.concatenate([x - offset, x + offset]), (spp, 1))
    sampler = sensor.sampler().clone()
    # An opaque seed: a new seed is a new kernel input, not a recompilation
    sampler.seed(dr.opaque(mi.UInt32, seed), len(positions))
    pos = mi.Point2f(*(positions / [width, height]).T.astype(np.float32))
    ray, weight = sensor.sample_ray(0.0, sampler.next_1d(), pos, sampler.next_2d())
    radiance = integrator.sample(mode=dr.ADMode.Primal, scene=scene, sampler=sampler, ray=ray,
                                 depth=mi.UInt32(0), δL=None, δaovs=None, state_in=None,
                                 active=mi.Bool(True))[0]
    return weight * radiance


def _difference(radiance: mi.Spectrum, normal_dl: np.ndarray, spp: int) -> np.ndarray:
    """``(f_in - f_out) dl`` (n, channels) from :func:`_side_radiance`."""
    length = np.linalg.norm(normal_dl, axis=1, keepdims=True)
    values = numpy_array(radiance).reshape(spp, 2, len(normal_dl), -1).mean(axis=0)
    return (values[0] - values[1]) * np.maximum(length, 1e-30)


def outline_radiance_difference(scene: mi.Scene, sensor: mi.Sensor, integrator, x: np.ndarray,
                                normal_dl: np.ndarray, seed: int, spp: int) -> np.ndarray:
    """``(f(x - eps n) - f(x + eps n)) dl`` (the side the outward normal
    points away from first), (n, channels): the integrator's primal
    radiance of camera rays at both sides, averaged over ``spp`` samples."""
    return _difference(_side_radiance(scene, sensor, integrator, x, normal_dl, seed, spp), normal_dl, spp)


def _hidden(integrator, scene: mi.Scene, sensor: mi.Sensor, points: mi.Point3f) -> mi.Bool:
    """Whether something lies between the camera and the (detached) world
    points (not yet evaluated)."""
    origin = sensor.world_transform() @ mi.Point3f(0.0)
    to_point = points - origin
    distance = dr.norm(to_point)
    ray = mi.Ray3f(origin, to_point / distance)
    # A ray to a tangent point may graze the surface just before it
    ray.maxt = distance * 0.99
    return integrator.geometry(scene).ray_test(ray, mi.Bool(True))


def outline_visible(integrator, scene: mi.Scene, sensor: mi.Sensor, points: mi.Point3f) -> np.ndarray:
    """Whether the camera sees the outline points (world, detached):
    nothing hit on the way there. Hidden outline pieces (the far side of the
    lathe, or behind other shapes) move no visible edge; their difference
    either side would only pick up the shading gradient of what hides
    them."""
    return ~np.array(_hidden(integrator, scene, sensor, points))


def _outline_terms(integrator, scene: mi.Scene, sensor: mi.Sensor, seed: int, spp: int,
                   samples: OutlineSamples | None = None):
    """Per lathe: the pixel ``(row, column, inside)`` of its outline pieces
    (``samples``, default :func:`outline_samples`), their detached weight
    ``(f_in - f_out) dl`` (n, channels) and their attached ``n . x``. The
    radiance either side of all pieces is traced in one wavefront, with a
    seed of its own (independent of the image's)."""
    if samples is None:
        samples = outline_samples(sensor, differentiable_lathes(integrator.geometry(scene).lathes))
    parts = samples.merged()
    if not parts:
        return
    width, height = sensor.film().crop_size()
    x = np.concatenate([part[5] for part in parts])
    normal_dl = np.concatenate([part[4] for part in parts])
    offset = np.concatenate([part[6] for part in parts])
    positions = [attached_outline_positions(sensor, *part[:4]) for part in parts]
    # The side radiance and the visibility of the outline points
    # (outline_visible) in one evaluation
    hidden = [_hidden(integrator, scene, sensor, dr.detach(points)) for _, points in positions]
    radiance = _side_radiance(scene, sensor, integrator, x, normal_dl, seed + 7919, spp, offset)
    dr.eval(radiance, *hidden)
    weight = _difference(radiance, normal_dl, spp)
    weight *= ~np.concatenate([np.array(mask) for mask in hidden])[:, None]
    start = 0
    for (_, seg, _, _, part_normal_dl, part_x, _), (position, _) in zip(parts, positions, strict=True):
        unit = _unit(part_normal_dl)
        speed = position.x * jit_array(mi.Float, unit[:, 0]) + position.y * jit_array(mi.Float, unit[:, 1])
        column = np.floor(part_x[:, 0]).astype(np.int64)
        row = np.floor(part_x[:, 1]).astype(np.int64)
        inside = (column >= 0) & (column < width) & (row >= 0) & (row < height)
        yield (row, column, inside), weight[start:start + len(seg)], speed
        start += len(seg)


def outline_forward(integrator, scene: mi.Scene, sensor: mi.Sensor, seed: int, spp: int) -> np.ndarray:
    """Forward mode: the outline part of the gradient image (height, width,
    channels) for the tangents set on the lathes' ``points``."""
    width, height = sensor.film().crop_size()
    image = None
    for pixels, weight, speed in _outline_terms(integrator, scene, sensor, seed, spp):
        if image is None:
            image = np.zeros((height, width, weight.shape[1]))
        add_edge_tangents(image, pixels, weight, speed)
    return np.zeros((height, width, 3)) if image is None else image


def outline_backward(integrator, scene: mi.Scene, sensor: mi.Sensor, grad_in: np.ndarray, seed: int,
                     spp: int, samples: OutlineSamples | None = None) -> None:
    """Reverse mode: accumulate the outline part of the gradient of
    ``sum(grad_in * image)`` into the lathes' ``points`` (outline pieces
    ``samples``, default :func:`outline_samples`)."""
    for pixels, weight, speed in _outline_terms(integrator, scene, sensor, seed, spp, samples):
        backward_edge_terms(pixels, weight, speed, grad_in)
