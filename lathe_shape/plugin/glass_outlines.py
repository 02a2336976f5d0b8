"""Outlines seen through glass: edge sampling of the lathes' outlines that
the camera sees through Dirac-delta chains (secondary visibility).

The silhouette term (silhouette.py) differentiates the outlines the camera
sees directly. Seen through a glass's wall, a straw in the glass, the inner
rim, the far wall or a solid stem draw outlines inside the glass's image
too, and they move with the profile (of the object seen, and of the glass
it is seen through). Across such an outline the camera ray's chain of
Dirac-delta vertices meets a lathe once more or once less: at one vertex
``k >= 1`` the ray grazes a lathe (touches its surface, or clips a polyline
joint's circle). A crease seen through glass (a polyline joint whose two
segments' shading normals differ, eq. 10) is an outline too: across it the
chain's vertex ``k`` moves from one smooth patch of the profile to the
next, and the ray leaving it turns abruptly; its contact is the joint's
circle, as for a clipped joint. With ``g(x, theta)`` the distance between
that ray, a function of the image position ``x`` and of the profile
``theta``, and the surface it grazes (or the crease's circle), the outline is ``g = 0`` and a pixel's gradient
gains (docs/method.md, eq. 41)

    dI_p = integral over the outline in p of (f_+ - f_-) g_theta / |grad_x g| dl,

``f_+`` and ``f_-`` the radiance on the sides where ``g > 0`` and
``g < 0``. By the envelope theorem the derivatives of that distance are
those of ``n . (o + t* d - q)`` with the contact held: ``o + t* d`` the
ray's point of contact, ``q`` the surface's (a material point of the
profile, attached to its points) and ``n`` the unit normal of the contact,
orthogonal to the ray (the surface normal at a tangency, ``d x T`` at a
joint circle whose tangent is ``T``).

The crossings are found on scan lines, ``lines`` per pixel across the rows
and as many down the columns, each sampled four times per pixel from a
random offset: where two neighbouring samples' chains meet a different
sequence of lathes, or of smooth patches of their profiles, bisection finds
the crossing. A crossing on a row stands for ``1 / lines`` of outline
length divided by ``|n_x|``, on a column by ``|n_y|``; weighted by the balance heuristic between the two,
each crossing adds (eq. 42)

    W (L_+ - L_-) g_theta / (p lines (|g_x| + |g_y|)),

whatever the outline's direction: ``g_x, g_y`` are central differences of
the detached chains, ``g_theta`` the attached chain's derivative (the hits
attached to the profile, the directions turned as eq. 28 says, none held
near grazing), ``W (L_+ - L_-)`` the chain's weight times the integrator's
primal radiance from vertex ``k`` on either side of the crossing, along
``grad_x g``, and ``p`` the probability that a scan line follows the
chain's branches (eq. 43): half the lines refract at every vertex (reflect
only where they must: total internal reflection, a mirror), the other
half reflect at one vertex drawn among the first eight (fewer if
``max_depth`` is lower). Chains that reflect
twice where they could refract (a weight ``F^2``, under 1% on glass seen
off grazing) and outlines of shapes other than lathes seen through glass
(their image moves with the glass too) are left out.
"""

from __future__ import annotations

import dataclasses

import drjit as dr
import mitsuba as mi
import numpy as np

from ..kernels.attached import profile_point
from ..surfaces import kind_of
from .attached_hits import attach_lathe_hits, attached_direction, differentiable_lathes
from .edge_terms import add_edge_tangents, backward_edge_terms, jit_array, numpy_array

__all__ = ["GLASS_OUTLINE_LINES", "GlassCrossings", "glass_outline_backward", "glass_outline_crossings",
           "glass_outline_forward"]

#: Scan lines per pixel, across the rows and down the columns (the
#: default of ``lathe_prb``'s ``glass_outline_lines``).
GLASS_OUTLINE_LINES = 1

#: Samples along a scan line, per pixel: two outline crossings closer than
#: 1 / this on a line are missed.
_SAMPLES_PER_PIXEL = 4

#: The share of scan lines whose chains reflect at one vertex (the others
#: always refract, eq. 43), and the vertices it is drawn among.
_REFLECTING_SHARE = 0.5
_REFLECTION_VERTICES = 8

#: Bisection steps: the crossing is found to 2^-12 of a sample spacing.
_BISECTIONS = 12

#: The most chain vertices followed (a path's depth bounds them too).
_MAX_VERTICES = 12

#: Central differences of ``g`` in the image: half step, pixels.
_IMAGE_STEP = 0.02

#: Side rays either side of a crossing, pixels (as the silhouette term's).
_EPSILON = 0.1

#: Two chains a bisection step apart part at the first vertex whose hit
#: distances differ by more than this fraction (deep in a solid stem, where
#: light reflects inside many times, chains that part nowhere drift apart
#: by 1e-3).
_PARTING = 0.05

#: Eq. 30's grazing cosine for the chain that reaches a crossing: the
#: derivative is taken at one path, whose chain is smooth in the profile.
_NO_GRAZING_HOLD = 1e-6

#: A hit within this cosine of grazing is a tangency (smooth contact).
_TANGENT_COSINE = 0.1

#: A hit within this fraction of the profile's size from a polyline joint
#: is a contact with the joint's circle.
_JOINT_DISTANCE = 1e-3


def _bucket(count: int) -> int:
    """``count`` rounded up to a power of two (at least 256): the size of
    the arrays whose size the kernels hold as a constant (scatter targets),
    so that a new count seldom compiles new kernels."""
    return max(256, 1 << (max(count, 1) - 1).bit_length())


@dataclasses.dataclass
class _Lanes:
    """Camera rays of the scan: image ``x`` (n, 2, pixels), and per lane the
    chain vertex where its scan line takes the reflection (``reflect_at``,
    -1 for none: always the refraction, eq. 43)."""

    x: np.ndarray
    reflect_at: np.ndarray

    def at(self, x: np.ndarray) -> _Lanes:
        """The same lanes' branches at other image positions."""
        return _Lanes(x, self.reflect_at)

    def tiled(self, times: int) -> _Lanes:
        return _Lanes(self.x, np.tile(self.reflect_at, times))

    def take(self, index: np.ndarray) -> _Lanes:
        return _Lanes(self.x[index], self.reflect_at[index])

    def rays(self, sensor: mi.Sensor) -> tuple[mi.Ray3f, mi.Int32]:
        """The camera rays, and the vertex where each reflects."""
        width, height = sensor.film().crop_size()
        pos = jit_array(mi.Point2f, (self.x / [width, height]).T)
        ray, _ = sensor.sample_ray(0.0, 0.5, pos, mi.Point2f(0.5))
        return ray, jit_array(mi.Int32, self.reflect_at)


def _lathe_index(si: mi.SurfaceInteraction3f, lathes: list) -> mi.Int32:
    """Index into ``lathes`` of the shape hit (-1: another shape, or none)."""
    index = dr.full(mi.Int32, -1, dr.width(si.t))
    for j, lathe in enumerate(lathes):
        index = dr.select(si.is_valid() & (si.shape == mi.ShapePtr(lathe)), j, index)
    return index


def _branch(si: mi.SurfaceInteraction3f, ray: mi.Ray3f, reflect_at: mi.Int32, depth, active: mi.Bool):
    """The chain's Dirac-delta branch at ``si``: the reflection at the
    lane's vertex ``reflect_at``, elsewhere the refraction (the reflection
    under total internal reflection, or off a mirror); with whether it goes
    on (a delta lobe was drawn) and the sample's weight."""
    bsdf = si.bsdf(ray)
    number = dr.select(mi.Int32(depth) == reflect_at, 0.0, 1.0 - 1e-6)  # (depth: int or UInt32)
    bs, weight = bsdf.sample(mi.BSDFContext(), si, number, mi.Point2f(0.5), active)
    go = active & mi.has_flag(bs.sampled_type, mi.BSDFFlags.Delta) & (bs.pdf > 0.0)
    return bsdf, bs, go, weight


@dr.syntax
def _signature(geometry, lathes: list, patches: _Patches, ray: mi.Ray3f, reflect_at: mi.Int32,
               vertices: mi.UInt32) -> mi.UInt32:
    """A hash of the sequence of lathes, and of their profiles' smooth
    patches, that the chains of ``ray`` meet (one loop): it changes across
    an outline seen through glass, where a lathe is met once more or less,
    another lathe is met instead, or a hit crosses a crease."""
    signature = dr.zeros(mi.UInt32, dr.width(ray.o))  # Hash of the lathes met so far
    active = dr.full(mi.Bool, True, dr.width(ray.o))  # The chain goes on
    depth = dr.zeros(mi.UInt32, dr.width(ray.o))  # Vertices so far
    while active:
        si = geometry.ray_intersect(ray, active)
        index = _lathe_index(si, lathes)
        on_lathe = active & (index >= 0)
        patch = patches.of_hits(index, si.prim_index, on_lathe)
        signature[on_lathe] = (signature * 0x9E3779B1 + mi.UInt32(index + 2)) * 0x85EBCA6B + patch
        _, bs, go, _ = _branch(si, ray, reflect_at, depth, on_lathe)
        ray = si.spawn_ray(si.to_world(bs.wo))
        depth += 1
        active = go & (depth < vertices)
    return signature


def _signatures(geometry, lathes: list, patches: _Patches, sensor: mi.Sensor, lanes: _Lanes,
                vertices: int) -> np.ndarray:
    """:func:`_signature` of each scan lane's chain."""
    ray, reflect_at = lanes.rays(sensor)
    return np.array(_signature(geometry, lathes, patches, ray, reflect_at, dr.opaque(mi.UInt32, vertices)))


@dr.syntax
def _bisect(geometry, lathes: list, patches: _Patches, sensor: mi.Sensor, a: _Lanes, b: _Lanes,
            vertices: int) -> tuple[_Lanes, _Lanes]:
    """Bisection of the pairs ``(a, b)`` (same branches, chains meeting
    a different sequence of lathes) to :data:`_BISECTIONS` halvings,
    in one kernel."""
    count = len(a.x)
    # (lanes past count repeat the last: kernels of a few sizes)
    padded = np.minimum(np.arange(_bucket(count)), count - 1)
    a, b = a.take(padded), b.take(padded)
    width, height = sensor.film().crop_size()
    scale = mi.ScalarVector2f(1.0 / width, 1.0 / height)
    ray_a, reflect_at = a.rays(sensor)
    last = dr.opaque(mi.UInt32, vertices)
    signature_a = _signature(geometry, lathes, patches, ray_a, reflect_at, last)
    x_a = jit_array(mi.Point2f, a.x.T)  # The side counted as a
    x_b = jit_array(mi.Point2f, b.x.T)  # ... and the other
    step = dr.zeros(mi.UInt32, dr.width(x_a))  # Halvings so far
    while step < _BISECTIONS:
        middle = 0.5 * (x_a + x_b)
        ray, _ = sensor.sample_ray(0.0, 0.5, middle * scale, mi.Point2f(0.5))
        same = _signature(geometry, lathes, patches, ray, reflect_at, last) == signature_a
        x_a = dr.select(same, middle, x_a)
        x_b = dr.select(same, x_b, middle)
        step += 1
    x_a, x_b = (numpy_array(x, np.float64)[:count] for x in (x_a, x_b))
    return a.take(np.arange(count)).at(x_a), b.take(np.arange(count)).at(x_b)


@dataclasses.dataclass
class _Chain:
    """Per vertex (first axis), per lane: the detached ray that reaches the
    vertex (``o``, ``d``), its hit (``t``, ``p``, ``n``, ``prim``,
    ``uv_y``), the lathe hit (index, -1 for none), whether the chain goes
    on past it, and whether it reflected there where it could have
    refracted (``optional``) or where it must (``sure``: total internal
    reflection, a mirror) (numpy)."""

    o: np.ndarray
    d: np.ndarray
    t: np.ndarray
    p: np.ndarray
    n: np.ndarray
    prim: np.ndarray
    uv_y: np.ndarray
    lathe: np.ndarray
    go: np.ndarray
    optional: np.ndarray
    sure: np.ndarray


class _Patches:
    """The smooth patches of the lathes' profiles: per lathe, the patch of
    each segment, counted from 0 and new after every crease (a polyline
    joint whose two segments' shading normals differ there, eq. 10). The
    curves of the B-spline kernel are one patch each: a B-spline is C2; the
    corners of a ``bezier`` or ``catmull_rom`` curve are left out, as their
    contact (a joint circle) is placed on polylines only (:func:`_contacts`)."""

    def __init__(self, lathes: list):
        self.per_lathe = []
        for lathe in lathes:
            profile = lathe.profile
            patch = np.zeros(profile.segment_count, dtype=np.int64)
            if kind_of(lathe.surface).kernel != "bspline":
                # segment k starts a new patch unless it goes on smoothly
                # from the segment before it (same joint, same normal; with
                # smooth false every joint is a crease: flat shading)
                linked = profile.segments[1:, 0] == profile.segments[:-1, 1]
                smooth = linked & np.all(np.abs(profile.normal_start[1:] - profile.normal_end[:-1]) < 1e-9,
                                         axis=1) & bool(lathe.smooth)
                patch[1:] = np.cumsum(~smooth)
                wrap = (profile.closed_loop and lathe.smooth
                        and profile.segments[0, 0] == profile.segments[-1, 1]
                        and np.all(np.abs(profile.normal_start[0] - profile.normal_end[-1]) < 1e-9))
                if wrap and patch[-1] >= 2:
                    # a loop's last patch goes on into its first (with a
                    # single crease the two stay apart: that crease parts them)
                    patch[patch == patch[-1]] = 0
            self.per_lathe.append(patch)
        offsets = np.cumsum([0] + [len(p) for p in self.per_lathe])
        self.offsets = jit_array(mi.UInt32, offsets[:-1])
        self.patch = jit_array(mi.UInt32, np.concatenate(self.per_lathe + [np.zeros(1, np.int64)]))

    def of_hits(self, index: mi.Int32, prim: mi.UInt32, active: mi.Bool) -> mi.UInt32:
        """The patch of each lathe hit (``index`` into the lathes, -1 for
        none: 0)."""
        start = dr.gather(mi.UInt32, self.offsets, mi.UInt32(dr.maximum(index, 0)), active)
        return dr.gather(mi.UInt32, self.patch, start + prim, active)

    def of_chain(self, chain: _Chain) -> np.ndarray:
        """The patch of each vertex of a recorded chain (-1: no lathe; a
        lathe hit's ``prim`` is its segment)."""
        out = np.full(chain.lathe.shape, -1, dtype=np.int64)
        for j, patch in enumerate(self.per_lathe):
            mine = chain.lathe == j
            out[mine] = patch[chain.prim[mine].astype(np.int64)]
        return out


@dr.syntax
def _chain(geometry, lathes: list, sensor: mi.Sensor, lanes: _Lanes, vertices: int) -> _Chain:
    """The detached chains of the scan lanes, recorded vertex by vertex (one
    loop)."""
    count = len(lanes.x)
    n = _bucket(count)  # (lanes past count repeat the last)
    lanes = lanes.take(np.minimum(np.arange(n), count - 1))
    ray, reflect_at = lanes.rays(sensor)
    size = vertices * n
    store = _Chain(o=dr.zeros(mi.Point3f, size), d=dr.zeros(mi.Vector3f, size),
                   t=dr.full(mi.Float, dr.inf, size), p=dr.zeros(mi.Point3f, size),
                   n=dr.zeros(mi.Vector3f, size),
                   prim=dr.zeros(mi.UInt32, size), uv_y=dr.zeros(mi.Float, size),
                   lathe=dr.full(mi.Int32, -1, size), go=dr.zeros(mi.UInt32, size),
                   optional=dr.zeros(mi.UInt32, size), sure=dr.zeros(mi.UInt32, size))
    lane = dr.arange(mi.UInt32, n)
    lanes_count = dr.opaque(mi.UInt32, n)
    last = dr.opaque(mi.UInt32, vertices)
    active = dr.full(mi.Bool, True, n)  # The chain goes on
    depth = dr.zeros(mi.UInt32, n)  # Vertices so far
    while active:
        si = geometry.ray_intersect(ray, active)
        index = _lathe_index(si, lathes)
        _, bs, go, _ = _branch(si, ray, reflect_at, depth, active & (index >= 0))
        reflected = go & mi.has_flag(bs.sampled_type, mi.BSDFFlags.DeltaReflection)
        slot = depth * lanes_count + lane
        values = dict(o=ray.o, d=ray.d, t=dr.select(si.is_valid(), si.t, dr.inf), p=si.p, n=mi.Vector3f(si.n),
                      prim=si.prim_index, uv_y=si.uv.y, lathe=index, go=mi.UInt32(go),
                      optional=mi.UInt32(reflected & (bs.pdf < 1.0)),
                      sure=mi.UInt32(reflected & (bs.pdf >= 1.0)))
        for name, value in values.items():
            dr.scatter(getattr(store, name), value, slot, active)
        ray = si.spawn_ray(si.to_world(bs.wo))
        depth += 1
        active = go & (depth < last)
    fields = [field.name for field in dataclasses.fields(_Chain)]
    dr.eval(*(getattr(store, name) for name in fields))
    out = {}
    for name in fields:
        value = numpy_array(getattr(store, name))
        value = value.reshape(vertices, n, -1) if value.ndim == 2 else value.reshape(vertices, n)
        value = value[:, :count]
        out[name] = value.astype(bool) if name in ("go", "optional", "sure") else value
    return _Chain(**out)


def _prefix(geometry, lathes: list, sensor: mi.Sensor, lanes: _Lanes, k: np.ndarray, vertices: int,
            attached: bool) -> tuple[mi.Ray3f, mi.Spectrum]:
    """The ray that reaches vertex ``k`` (per lane) of the lanes' chains and
    the chain's weight before it (the product of its branches' BSDF values,
    eq. 42); with ``attached``, the ray follows the profile points (eq. 28)
    and the weight is left out."""
    ray, reflect_at = lanes.rays(sensor)
    throughput = dr.ones(mi.Spectrum, dr.width(ray.o))
    k = jit_array(mi.UInt32, k)
    # (always ``vertices`` steps: the kernels, and the reverse pass's, are
    # the same whatever the deepest crossing)
    for vertex in range(vertices):
        # (an opaque depth: every vertex runs the same kernel, evaluated
        # vertex by vertex, as lathe_prb's differential pass does)
        depth = dr.opaque(mi.UInt32, vertex)
        active = depth < k
        # (found on the detached ray: the chain's vertices are lathes, whose
        # hits are attached here; no other shape's is differentiated)
        si = geometry.ray_intersect(dr.detach(ray), active)
        bsdf, bs, _, weight = _branch(si, ray, reflect_at, depth, active)
        wo_world = si.to_world(bs.wo)
        if attached:
            # The detached values evaluated with the vertex: the reverse
            # pass reads them instead of tracing the rays again (whose
            # kernels it would compile anew at every call)
            stored = [si, bs, wo_world]
            dr.eval(stored)
            si = attach_lathe_hits(lathes, ray, si)
            # (no grazing hold, eq. 30: the contact's distance is smooth in
            # the profile, and a crossing is often seen through a wall near
            # grazing)
            wo_world, _ = attached_direction(bsdf, mi.BSDFContext(), si, bs, wo_world, mi.Point2f(0.5),
                                              active, (True, False), _NO_GRAZING_HOLD, stored)
            dr.eval(stored)
        else:
            throughput[active] *= weight * bs.pdf
        ray = dr.select(active, si.spawn_ray(wo_world), ray)
        dr.eval(ray, throughput)
    return ray, throughput


@dataclasses.dataclass
class GlassCrossings:
    """Outline crossings seen through glass (numpy): the scan ``lanes`` at
    the crossings (image position, branch choices), each crossing's weight
    ``scale``, ``1 / (lines p)`` with ``p`` the probability of its chain's
    branches (eq. 43), and the chain's grazing vertex ``k``; the contact's
    lathe (index into the differentiable lathes), material point (``seg``,
    ``u``, ``phi``), unit normal ``n`` and parameter ``t_star`` along the
    ray (world), the image gradient ``grad_g`` of the distance ``g`` (n, 2)
    and the detached contact point ``q`` (world). ``found``: crossings
    bisected; ``dropped``: of those, the ones left out (no grazing contact
    with a lathe: a change of branch, or total internal reflection, that
    turns the ray; another shape's outline; another outline between the
    side rays)."""

    lanes: _Lanes
    scale: np.ndarray
    k: np.ndarray
    lathe: np.ndarray
    seg: np.ndarray
    u: np.ndarray
    phi: np.ndarray
    n: np.ndarray
    t_star: np.ndarray
    grad_g: np.ndarray
    q: np.ndarray
    found: int = 0
    dropped: int = 0

    @property
    def x(self) -> np.ndarray:
        return self.lanes.x

    def __len__(self) -> int:
        return len(self.lanes.x)

    @staticmethod
    def none(found: int = 0) -> GlassCrossings:
        empty, vectors = np.zeros(0), np.zeros((0, 3))
        lanes = _Lanes(np.zeros((0, 2)), np.zeros(0, dtype=np.int64))
        return GlassCrossings(lanes, empty, *(np.zeros(0, dtype=np.int64),) * 3, empty, empty, vectors, empty,
                              np.zeros((0, 2)), vectors, found, found)


def _screen_region(sensor: mi.Sensor, lathes: list) -> tuple[np.ndarray, np.ndarray]:
    """The pixels ``[low, high)`` (x, y) that can see a lathe with a
    Dirac-delta BSDF (a chain's first vertex): the image of their bounding
    boxes, a pixel wider; the whole image where a box reaches behind the
    camera."""
    width, height = sensor.film().crop_size()
    whole = np.array([0, 0]), np.array([width, height])
    boxes = [lathe.bbox() for lathe in lathes if mi.has_flag(lathe.bsdf().flags(), mi.BSDFFlags.Delta)]
    if not boxes:
        return whole[0], whole[0]
    corners = np.array([[(box.min, box.max)[(c >> i) & 1][i] for i in range(3)]
                        for box in boxes for c in range(8)])
    to_camera = np.array(sensor.world_transform().inverse().matrix, dtype=np.float64).reshape(4, 4)
    depth = (np.c_[corners, np.ones(len(corners))] @ to_camera.T)[:, 2]
    if np.any(depth <= 0.0):
        return whole
    it = dr.zeros(mi.Interaction3f, len(corners))
    it.p = jit_array(mi.Point3f, corners.T)
    ds, _ = sensor.sample_direction(it, mi.Point2f(0.5))
    image = numpy_array(ds.uv, np.float64)
    low = np.clip(np.floor(image.min(axis=0)) - 1, 0, [width, height]).astype(int)
    high = np.clip(np.ceil(image.max(axis=0)) + 1, 0, [width, height]).astype(int)
    return low, np.maximum(high, low)


def _scan(sensor: mi.Sensor, geometry, lathes: list, patches: _Patches, rng: np.random.Generator, lines: int,
          vertices: int, reflection_vertices: int) -> tuple[_Lanes, _Lanes]:
    """Pairs of scan lanes ``(a, b)`` on the scan lines whose chains meet
    a different sequence of lathes, bisected. A share of the lines
    (:data:`_REFLECTING_SHARE`, at random) reflects at one vertex, drawn
    among the first ``reflection_vertices`` (eq. 43)."""
    low, high = _screen_region(sensor, lathes)
    pairs = []
    for axis in (0, 1):  # rows (x varies), then columns (y varies)
        start, stop = low[1 - axis], high[1 - axis]  # the lines' range across ...
        first, last = low[axis], high[axis]  # ... and along them (whole pixels)
        count = (stop - start) * lines
        if count == 0 or last <= first:
            continue
        offset = start + (np.arange(count) + rng.uniform(size=count)) / lines
        step = 1.0 / _SAMPLES_PER_PIXEL
        along = first + np.arange(-1, int(np.ceil((last - first) / step)) + 1) * step
        along = along[None, :] + rng.uniform(0, step, (count, 1))
        positions = np.empty(along.shape + (2,))
        positions[..., axis] = along
        positions[..., 1 - axis] = offset[:, None]
        reflect_at = np.where(rng.uniform(size=count) < _REFLECTING_SHARE,
                              rng.integers(0, reflection_vertices, count), -1)
        scan = _Lanes(positions.reshape(-1, 2), np.repeat(reflect_at, along.shape[1]))
        signatures = _signatures(geometry, lathes, patches, sensor, scan, vertices).reshape(along.shape)
        # (each line's last sample starts no pair)
        change = np.concatenate([signatures[:, 1:] != signatures[:, :-1], np.zeros((count, 1), bool)], 1)
        first = np.flatnonzero(change.ravel())
        pairs.append((scan.take(first), scan.take(first + 1)))
    if not pairs:
        nothing = _Lanes(np.zeros((0, 2)), np.zeros(0, dtype=np.int64))
        return nothing, nothing
    a = _Lanes(*(np.concatenate([getattr(pair[0], f) for pair in pairs]) for f in ("x", "reflect_at")))
    b = a.at(np.concatenate([pair[1].x for pair in pairs]))
    if len(a.x) == 0:
        return a, b
    a, b = _bisect(geometry, lathes, patches, sensor, a, b, vertices)
    return a, b


def _first_difference(chain_a: _Chain, chain_b: _Chain, patches: _Patches) -> np.ndarray:
    """Per lane, the first vertex where the two chains part (-1: none):
    another lathe or none, a hit much further, or a hit across a crease."""
    vertices, lanes = chain_a.t.shape
    patch_a, patch_b = patches.of_chain(chain_a), patches.of_chain(chain_b)
    k = np.full(lanes, -1)
    going = np.ones(lanes, dtype=bool)
    for v in range(vertices):
        ta, tb = chain_a.t[v], chain_b.t[v]
        with np.errstate(invalid="ignore"):
            jump = np.abs(ta - tb) > _PARTING * np.minimum(ta, tb) + 1e-6
        differ = ((chain_a.lathe[v] != chain_b.lathe[v]) | (np.isfinite(ta) != np.isfinite(tb))
                  | (patch_a[v] != patch_b[v]))
        parted = going & (k < 0) & (differ | (np.isfinite(ta) & jump))
        k[parted] = v
        going &= chain_a.go[v] & chain_b.go[v]
    return k


def _contacts(lathes: list, chain: _Chain, k: np.ndarray, lanes: np.ndarray):
    """The grazing contact at vertex ``k`` of ``chain`` (its lanes
    ``lanes``): lathe, material point, unit normal, ``t*`` and contact
    point (world), with which lanes make one."""
    count = len(lanes)
    at = (k[lanes], lanes)
    o, d, p, n_geo = chain.o[at], chain.d[at], chain.p[at], chain.n[at]
    d = d / np.linalg.norm(d, axis=1, keepdims=True)
    lathe_of = chain.lathe[at]
    keep = np.zeros(count, dtype=bool)
    seg, u, phi = np.zeros(count, dtype=np.int64), np.zeros(count), np.zeros(count)
    normal, t_star, q = np.zeros((count, 3)), chain.t[at].copy(), p.copy()
    cosine = np.abs(np.sum(n_geo * d, axis=1))
    for j, lathe in enumerate(lathes):
        mine = np.flatnonzero(lathe_of == j)
        if len(mine) == 0:
            continue
        m = lathe.to_world_matrix
        local = (p[mine] - m[:3, 3]) @ np.linalg.inv(m[:3, :3]).T
        rho, z = np.hypot(local[:, 0], local[:, 1]), local[:, 2]
        azimuth = np.arctan2(local[:, 1], local[:, 0])
        prim = chain.prim[at][mine].astype(np.int64)
        tangent = cosine[mine] < _TANGENT_COSINE
        joint = np.zeros(len(mine), dtype=bool)
        joint_u = np.zeros(len(mine))
        if kind_of(lathe.surface).kernel == "bspline":
            u_mine = chain.uv_y[at][mine] * lathe.profile.segment_count - prim
        else:
            profile = lathe.profile
            p0, p1 = profile.segment_points()
            delta = p1[prim] - p0[prim]
            along = np.sum((np.stack([rho, z], 1) - p0[prim]) * delta, 1)
            u_mine = np.clip(along / np.sum(delta**2, 1), 0, 1)
            size = np.ptp(profile.points, axis=0).max()
            m_seg = profile.segment_count
            ends = ((1.0, p1[prim], (prim + 1) % m_seg), (0.0, p0[prim], (prim - 1) % m_seg))
            for end, point, neighbour in ends:
                near = np.hypot(rho - point[:, 0], z - point[:, 1]) < _JOINT_DISTANCE * size
                if end == 1.0:
                    linked = profile.segments[prim, 1] == profile.segments[neighbour, 0]
                else:
                    linked = profile.segments[prim, 0] == profile.segments[neighbour, 1]
                at_joint = near & linked & (point[:, 0] > 0.0) & ~joint
                joint |= at_joint
                joint_u = np.where(at_joint, end, joint_u)
                # The contact is on the joint's circle, at the hit's azimuth
                circle = np.stack([point[:, 0] * np.cos(azimuth), point[:, 0] * np.sin(azimuth),
                                   point[:, 1]], 1)
                q_world = circle @ m[:3, :3].T + m[:3, 3]
                q[mine[at_joint]] = q_world[at_joint]
        # A joint's normal: across the ray and the circle's tangent
        t_local = np.stack([-np.sin(azimuth), np.cos(azimuth), np.zeros_like(azimuth)], 1)
        t_world = t_local @ m[:3, :3].T
        across = np.cross(d[mine], t_world)
        along_surface = n_geo[mine] - np.sum(n_geo[mine] * d[mine], 1, keepdims=True) * d[mine]
        chosen = np.where(joint[:, None], across, along_surface)
        length = np.linalg.norm(chosen, axis=1)
        ok = (joint | tangent) & (length > 1e-6)
        normal[mine] = chosen / np.maximum(length, 1e-30)[:, None]
        t_star[mine] = np.where(joint, np.sum((q[mine] - o[mine]) * d[mine], 1), t_star[mine])
        seg[mine], u[mine], phi[mine] = prim, np.where(joint, joint_u, u_mine), azimuth
        keep[mine] = ok
    return keep, lathe_of, seg, u, phi, normal, t_star, q


def glass_outline_crossings(integrator, scene: mi.Scene, sensor: mi.Sensor, seed: int,
                            lines: int = GLASS_OUTLINE_LINES) -> GlassCrossings:
    """The outline crossings seen through glass in ``sensor``'s image
    (``lines`` scan lines per pixel each way, jittered by ``seed``)."""
    geometry = integrator.geometry(scene)
    lathes = differentiable_lathes(geometry.lathes)
    vertices = int(min(integrator.max_depth, _MAX_VERTICES))
    rng = np.random.default_rng([seed, 7727])
    with dr.suspend_grad():
        reflection_vertices = min(vertices, _REFLECTION_VERTICES)
        patches = _Patches(lathes)
        a, b = _scan(sensor, geometry, lathes, patches, rng, lines, vertices, reflection_vertices)
        if len(a.x) == 0:
            return GlassCrossings.none()
        chain_a = _chain(geometry, lathes, sensor, a, vertices)
        chain_b = _chain(geometry, lathes, sensor, b, vertices)
        k = _first_difference(chain_a, chain_b, patches)
        # The side that meets the grazed lathe (the nearer hit at vertex k)
        lanes = np.arange(len(a.x))
        kk = np.maximum(k, 0)
        b_nearer = chain_b.t[kk, lanes] < chain_a.t[kk, lanes]
        near = _Chain(**{name: np.where(b_nearer.reshape((1, -1) + (1,) * (getattr(chain_a, name).ndim - 2)),
                                        getattr(chain_b, name), getattr(chain_a, name))
                         for name in (field.name for field in dataclasses.fields(_Chain))})
        x = np.where(b_nearer[:, None], b.x, a.x)
        # Both sides' rays at vertex k must agree (else the chain changed
        # branch before it, or was totally reflected: the ray turned)
        same_ray = np.linalg.norm(chain_a.d[kk, lanes] - chain_b.d[kk, lanes], axis=1) < 1e-3
        candidate = np.flatnonzero((k >= 1) & same_ray & np.isfinite(near.t[kk, lanes])
                                   & (near.lathe[kk, lanes] >= 0))
        keep, lathe_of, seg, u, phi, normal, t_star, q = _contacts(lathes, near, kk, candidate)
        chosen = candidate[keep]
        if len(chosen) == 0:
            return GlassCrossings.none(len(a.x))
        # Eq. 43: the probability that a scan line follows the chain's
        # branches before vertex k: a chain that reflects nowhere it could
        # refract is followed by the refracting lines and by the reflecting
        # ones whose vertex is a sure reflection or lies at k or beyond; one
        # that reflects once where it could refract, by the lines that
        # reflect there
        before = np.arange(near.optional.shape[0])[:, None] < kk[None, :]
        optional = np.sum(near.optional & before, axis=0)
        early = np.arange(near.sure.shape[0])[:, None] < reflection_vertices
        alike = np.maximum(reflection_vertices - kk, 0) + np.sum(near.sure & before & early, axis=0)
        share = _REFLECTING_SHARE
        probability = np.where(optional == 0, 1.0 - share + share * alike / reflection_vertices,
                               share / reflection_vertices)
        crossing = a.take(chosen).at(x[chosen])
        k_c = kk[chosen]
        # g's image gradient by central differences of the detached chains
        shifts = np.array([[_IMAGE_STEP, 0.0], [-_IMAGE_STEP, 0.0], [0.0, _IMAGE_STEP], [0.0, -_IMAGE_STEP]])
        shifted_lanes = crossing.tiled(4).at(np.concatenate([crossing.x + shift for shift in shifts]))
        shifted = _chain(geometry, lathes, sensor, shifted_lanes, int(k_c.max()) + 1)
        lanes4 = np.arange(4 * len(chosen))
        k4 = np.tile(k_c, 4)
        o4, d4 = shifted.o[k4, lanes4], shifted.d[k4, lanes4]
        with np.errstate(invalid="ignore", divide="ignore"):
            d4 = d4 / np.linalg.norm(d4, axis=1, keepdims=True)
        n4, t4, q4 = np.tile(normal[keep], (4, 1)), np.tile(t_star[keep], 4), np.tile(q[keep], (4, 1))
        g = np.sum(n4 * (o4 + t4[:, None] * d4 - q4), axis=1).reshape(4, -1)
        grad_g = np.stack([g[0] - g[1], g[2] - g[3]], axis=1) / (2 * _IMAGE_STEP)
        # (a shifted chain that ended before vertex k: another outline within the step)
        grad_g[~np.isfinite(grad_g).all(axis=1)] = 0.0
        # The side rays of eq. 42 (a tenth of a pixel either way along
        # grad g) must part at vertex k themselves: where another outline
        # lies between them, their difference is not this one's (dropped)
        unit = grad_g / np.maximum(np.linalg.norm(grad_g, axis=1, keepdims=True), 1e-30)
        side_a = _chain(geometry, lathes, sensor, crossing.at(crossing.x - _EPSILON * unit), vertices)
        side_b = _chain(geometry, lathes, sensor, crossing.at(crossing.x + _EPSILON * unit), vertices)
        parts = np.flatnonzero(_first_difference(side_a, side_b, patches) == k_c)
    if len(parts) == 0:
        return GlassCrossings.none(len(a.x))
    scale = 1.0 / (lines * np.maximum(probability[chosen], 1e-30))
    lathe_of, seg, u, phi, normal, t_star, q = (value[keep][parts]
                                                for value in (lathe_of, seg, u, phi, normal, t_star, q))
    return GlassCrossings(crossing.take(parts), scale[parts], k_c[parts], lathe_of, seg, u, phi, normal,
                          t_star, grad_g[parts], q, len(a.x), len(a.x) - len(parts))


def _terms(integrator, scene: mi.Scene, sensor: mi.Sensor, seed: int, spp: int, crossings: GlassCrossings):
    """The pixel ``(row, column, inside)`` of each crossing, its detached
    weight ``W (L_+ - L_-) / (p lines (|g_x| + |g_y|))`` (n, channels) and
    the attached ``g``, whose derivative completes eq. 42."""
    geometry = integrator.geometry(scene)
    lathes = differentiable_lathes(geometry.lathes)
    width, height = sensor.film().crop_size()
    grad_norm = np.linalg.norm(crossings.grad_g, axis=1, keepdims=True)
    unit = crossings.grad_g / np.maximum(grad_norm, 1e-30)
    # The jump: the chain's weight times the radiance that goes on from
    # vertex k, either side of the crossing (along grad g: f_- first)
    count = len(crossings)
    sides = crossings.lanes.tiled(2).at(np.concatenate([crossings.x - _EPSILON * unit,
                                                        crossings.x + _EPSILON * unit]))
    sides = sides.tiled(spp).at(np.tile(sides.x, (spp, 1)))
    vertices = int(min(integrator.max_depth, _MAX_VERTICES))
    ray, throughput = _prefix(geometry, lathes, sensor, sides, np.tile(crossings.k, 2 * spp), vertices, False)
    sampler = sensor.sampler().clone()
    # An opaque seed: a new seed is a new kernel input, not a recompilation
    sampler.seed(dr.opaque(mi.UInt32, seed + 104729), dr.width(ray.o))
    # (the paths go on from vertex k at its depth, as the image's do)
    depth = jit_array(mi.UInt32, np.tile(crossings.k, 2 * spp))
    radiance = integrator.sample_from(scene, sampler, ray, depth)
    values = numpy_array(throughput * radiance).reshape(spp, 2, count, -1).mean(axis=0)
    spread = np.abs(crossings.grad_g).sum(axis=1, keepdims=True)
    weight = (values[1] - values[0]) * crossings.scale[:, None] / np.maximum(spread, 1e-30)
    weight[spread[:, 0] <= 0.0] = 0.0
    # g = n . (o + t* d - q), attached (the contact held: envelope theorem)
    ray, _ = _prefix(geometry, lathes, sensor, crossings.lanes, crossings.k, vertices, True)
    contact = dr.zeros(mi.Point3f, len(crossings))
    seg = jit_array(mi.UInt32, crossings.seg)
    u = jit_array(mi.Float, crossings.u)
    phi = jit_array(mi.Float, crossings.phi)
    for j, lathe in enumerate(lathes):
        mine = jit_array(mi.Bool, crossings.lathe == j)
        # (segment 0 on the other lathes' lanes: their segments may not exist here)
        r, z = profile_point(lathe.profile_points, lathe.profile_index, kind_of(lathe.surface).kernel,
                             dr.select(mine, seg, 0), u)
        point = lathe._to_world @ mi.Point3f(r * dr.cos(phi), r * dr.sin(phi), z)
        contact = dr.select(mine, point, contact)
    normal = jit_array(mi.Vector3f, crossings.n.T)
    t_star = jit_array(mi.Float, crossings.t_star)
    direction = ray.d * dr.rsqrt(dr.squared_norm(dr.detach(ray.d)))
    g = dr.dot(normal, ray.o + t_star * direction - contact)
    column = np.floor(crossings.x[:, 0]).astype(np.int64)
    row = np.floor(crossings.x[:, 1]).astype(np.int64)
    inside = (column >= 0) & (column < width) & (row >= 0) & (row < height)
    return (row, column, inside), weight, g


def glass_outline_forward(integrator, scene: mi.Scene, sensor: mi.Sensor, seed: int, spp: int,
                          lines: int = GLASS_OUTLINE_LINES) -> np.ndarray:
    """Forward mode: the through-glass outline part of the gradient image
    (height, width, channels) for the tangents set on the lathes' points."""
    width, height = sensor.film().crop_size()
    image = np.zeros((height, width, 3))
    crossings = glass_outline_crossings(integrator, scene, sensor, seed, lines)
    if len(crossings) == 0:
        return image
    pixels, weight, g = _terms(integrator, scene, sensor, seed, spp, crossings)
    add_edge_tangents(image, pixels, weight, g)
    return image


def glass_outline_backward(integrator, scene: mi.Scene, sensor: mi.Sensor, grad_in: np.ndarray, seed: int,
                           spp: int, lines: int = GLASS_OUTLINE_LINES) -> None:
    """Reverse mode: accumulate the through-glass outline part of the
    gradient of ``sum(grad_in * image)`` into the lathes' points."""
    crossings = glass_outline_crossings(integrator, scene, sensor, seed, lines)
    if len(crossings) == 0:
        return
    pixels, weight, g = _terms(integrator, scene, sensor, seed, spp, crossings)
    backward_edge_terms(pixels, weight, g, grad_in)
