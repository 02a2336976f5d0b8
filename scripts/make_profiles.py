#!/usr/bin/env python3
"""Generate the profile CSVs of the three example scenes (deterministic).

    python scripts/make_profiles.py            # writes scenes/{wine_glass,sundae_cup,brandy_bottle}.csv
    python scripts/make_profiles.py --check    # only builds and checks, writes nothing

The objects are modelled on Horiuchi, Yokoi & Toriwaki (1987): a wine glass, a
sundae cup and a brandy bottle standing on a checkered floor (see
docs/method.md). Each profile is a closed polyline in the (r, z) half-plane of
the shape's local frame (axis = +z, r >= 0, centimetre-ish units), built only
from straight lines and circular arcs:

* every arc is divided equally with one fixed angular step per object, so the
  angle between successive segments is small and (nearly) the same everywhere
  -- the care the paper recommends in section 2.3 against a distorted view of
  the floor through the glass;
* every glass wall is made of an outer and an inner arc (or line) that are
  concentric, i.e. the wall has constant thickness, again as the paper advises;
* curves are joined tangentially (fillets), so the only real corners are the
  ones a glass maker makes on purpose: they carry ``sharp = 1`` (foot rim
  corners, the flat-cut lip of the bottle).

Output format (read by ``lathe_shape.profiles.polyline``): header ``r,z,sharp``, one
vertex per line, ``#`` comments. Both ends of every profile lie on the axis
(r = 0), which closes it. Points run clockwise in the (r right, z up) plane,
i.e. the glass is on the right-hand side when walking along the profile (the
paper's convention; the loader accepts either orientation). The lowest point
of every profile has z = 0 so the object stands on the floor with an identity
transform.

``check_profile`` verifies: finite values, r >= 0, closed, no consecutive
duplicates, no self-intersection (2D segment-segment test over all pairs of
non-adjacent segments, including the closing segment along the axis).
"""
from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

SCENES = Path(__file__).resolve().parent.parent / "scenes"
# The rim beads are tiny half circles (radius ~0.1); they get a coarser step
# than the rest of the profile to keep the point count in the tens.
RIM_STEP = 15.0


# --------------------------------------------------------------------------
# A tiny polyline builder: lines and equally divided circular arcs
# --------------------------------------------------------------------------
class Profile:
    def __init__(self, start, sharp=False, step_deg=7.5):
        self.pts = [np.asarray(start, dtype=float)]
        self.sharp = [bool(sharp)]
        self.step = math.radians(step_deg)

    @property
    def last(self):
        return self.pts[-1]

    def mark_sharp(self):
        """Flag the current last vertex as a sharp crease."""
        self.sharp[-1] = True

    def line(self, p, n=1, sharp=False):
        """Straight line to p, split into n equal segments."""
        p = np.asarray(p, dtype=float)
        p0 = self.last
        for k in range(1, n + 1):
            self.pts.append(p0 + (p - p0) * (k / n))
            self.sharp.append(False)
        self.sharp[-1] = bool(sharp)

    def arc(self, c, radius, a0, a1, sharp=False, step_deg=None):
        """Circular arc about c from angle a0 to a1 (radians, signed sweep).

        The arc must start at the current last point; it is divided into
        ceil(|a1 - a0| / step) equal parts (step: the profile's, or step_deg).
        """
        step = self.step if step_deg is None else math.radians(step_deg)
        c = np.asarray(c, dtype=float)
        start = c + radius * np.array([math.cos(a0), math.sin(a0)])
        gap = np.linalg.norm(start - self.last)
        assert gap < 1e-6, f"arc does not start at the last point (gap {gap:g})"
        n = max(1, math.ceil(abs(a1 - a0) / step - 1e-9))
        for k in range(1, n + 1):
            a = a0 + (a1 - a0) * k / n
            self.pts.append(c + radius * np.array([math.cos(a), math.sin(a)]))
            self.sharp.append(False)
        self.sharp[-1] = bool(sharp)

    def arc_to(self, c, p_end, sharp=False):
        """Shorter circular arc (sweep < 180 deg) about c from the last point
        to p_end (a fillet); both must be at the same distance from c."""
        c = np.asarray(c, dtype=float)
        v0, v1 = self.last - c, np.asarray(p_end, dtype=float) - c
        r0, r1 = np.linalg.norm(v0), np.linalg.norm(v1)
        assert abs(r0 - r1) < 1e-6, f"arc_to: radii differ ({r0:g} vs {r1:g})"
        a0 = ang(v0)
        sweep = (ang(v1) - a0 + math.pi) % (2 * math.pi) - math.pi
        self.arc(c, r0, a0, a0 + sweep, sharp=sharp)
        self.pts[-1] = np.asarray(p_end, dtype=float)  # exact end point

    def arrays(self):
        pts = np.array(self.pts)
        pts[np.abs(pts) < 1e-12] = 0.0  # clean -0.0 / round-off on the axis
        return pts, np.array(self.sharp, dtype=int)


def ang(v):
    return math.atan2(v[1], v[0])


def fillet_line_circle(r_line, center, radius, f, below=True):
    """Fillet of radius f between the vertical line r = r_line (material at
    r < r_line) and a circle (material inside), fillet centre outside both.

    Returns (fillet centre, tangent point on the line, tangent point on the
    circle). The fillet circle is externally tangent to the given circle.
    """
    cx = r_line + f
    dz = math.sqrt((radius + f) ** 2 - (cx - center[0]) ** 2)
    cz = center[1] - dz if below else center[1] + dz
    cf = np.array([cx, cz])
    t_line = np.array([r_line, cz])
    u = (cf - center) / np.linalg.norm(cf - center)
    t_circ = center + radius * u
    return cf, t_line, t_circ


def fillet_corner(x, a_in, b_out, rho):
    """Fillet of radius rho in the corner x between an incoming line with unit
    direction a_in (towards x) and an outgoing one with unit direction b_out.

    Returns (centre, first tangent point, second tangent point).
    """
    a = np.asarray(a_in, float) / np.linalg.norm(a_in)
    b = np.asarray(b_out, float) / np.linalg.norm(b_out)
    theta = math.acos(np.clip(a @ b, -1.0, 1.0))  # turning angle
    d = rho * math.tan(theta / 2)
    t1, t2 = x - a * d, x + b * d
    turn = a[0] * b[1] - a[1] * b[0]  # > 0: turns left
    n = np.array([-a[1], a[0]]) if turn > 0 else np.array([a[1], -a[0]])
    return t1 + rho * n, t1, t2


def orient_clockwise(pts, sharp):
    """Reverse the profile if it runs counter-clockwise in (r right, z up)."""
    closed = np.vstack([pts, pts[:1]])
    area2 = np.sum(closed[:-1, 0] * closed[1:, 1] - closed[1:, 0] * closed[:-1, 1])
    if area2 > 0:  # counter-clockwise
        return pts[::-1].copy(), sharp[::-1].copy()
    return pts, sharp


# --------------------------------------------------------------------------
# Checks
# --------------------------------------------------------------------------
def _segments_intersect(p1, p2, q1, q2, eps=1e-12):
    """Vectorised 2D test: does segment p1p2 intersect q1q2 (touching counts)?"""
    def cross(o, a, b):
        return (a[..., 0] - o[..., 0]) * (b[..., 1] - o[..., 1]) - \
               (a[..., 1] - o[..., 1]) * (b[..., 0] - o[..., 0])

    d1 = cross(q1, q2, p1)
    d2 = cross(q1, q2, p2)
    d3 = cross(p1, p2, q1)
    d4 = cross(p1, p2, q2)
    proper = (((d1 > eps) & (d2 < -eps)) | ((d1 < -eps) & (d2 > eps))) & \
             (((d3 > eps) & (d4 < -eps)) | ((d3 < -eps) & (d4 > eps)))

    def on_seg(a, b, p, d):
        return (np.abs(d) <= eps) & \
            (np.minimum(a[..., 0], b[..., 0]) - eps <= p[..., 0]) & \
            (p[..., 0] <= np.maximum(a[..., 0], b[..., 0]) + eps) & \
            (np.minimum(a[..., 1], b[..., 1]) - eps <= p[..., 1]) & \
            (p[..., 1] <= np.maximum(a[..., 1], b[..., 1]) + eps)

    touch = on_seg(q1, q2, p1, d1) | on_seg(q1, q2, p2, d2) | \
        on_seg(p1, p2, q1, d3) | on_seg(p1, p2, q2, d4)
    return proper | touch


def check_profile(name, pts, sharp):
    assert pts.ndim == 2 and pts.shape[1] == 2 and len(pts) >= 3, name
    assert np.all(np.isfinite(pts)), f"{name}: NaN/inf"
    assert np.all(pts[:, 0] >= 0), f"{name}: negative r"
    assert len(sharp) == len(pts), name
    step = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    assert np.all(step > 1e-9), f"{name}: consecutive duplicate points"
    ends_on_axis = pts[0, 0] == 0 and pts[-1, 0] == 0
    loop = np.allclose(pts[0], pts[-1])
    assert ends_on_axis or loop, f"{name}: profile not closed"
    # segments of the closed polygon (closing segment along the axis if open)
    ring = pts if loop else np.vstack([pts, pts[:1]])
    a, b = ring[:-1], ring[1:]
    m = len(a)
    i, j = np.triu_indices(m, k=2)
    adjacent_wrap = (i == 0) & (j == m - 1)
    i, j = i[~adjacent_wrap], j[~adjacent_wrap]
    hit = _segments_intersect(a[i], b[i], a[j], b[j])
    assert not hit.any(), (
        f"{name}: self-intersection between segments "
        f"{list(zip(i[hit].tolist(), j[hit].tolist(), strict=True))[:5]}")
    # turning angles (informative)
    d = np.diff(pts, axis=0)
    h = np.arctan2(d[:, 1], d[:, 0])
    turn = np.degrees(np.abs((np.diff(h) + np.pi) % (2 * np.pi) - np.pi))
    return turn


# --------------------------------------------------------------------------
# The objects (all lengths in cm)
# --------------------------------------------------------------------------
def wine_glass():
    """Wine glass, 18.1 tall: domed-under foot with a square-cut rim, slender
    stem with fillets, tulip bowl (sphere below the widest point, a gently
    inward-leaning arc above it) with a 0.18 wall and a round rim bead."""
    t = 0.18                      # bowl wall thickness
    foot_r, foot_h = 3.7, 0.25    # foot radius, rim edge height
    ring_r = 3.3                  # inner edge of the bearing ring at z = 0
    dome = 0.12                   # height of the domed underside at the axis
    stem_r = 0.35
    bowl_c = np.array([0.0, 11.0])  # centre of the lower (spherical) bowl
    bowl_R = 4.0                  # outer radius of the lower bowl
    top_z = 18.0                  # rim height (outer wall ends there)
    up_R = 30.0                   # radius of the upper, inward-leaning wall
    up_c = np.array([bowl_R - up_R, bowl_c[1]])  # tangent at the widest point
    foot_top_inner = np.array([stem_r, 0.62])  # where foot top meets stem (before fillet)

    p = Profile([0.0, dome], step_deg=7.5)
    # domed underside: arc centred on the axis through (0,dome) and (ring_r,0)
    R_d = (ring_r ** 2 + dome ** 2) / (2 * dome)
    c_d = np.array([0.0, dome - R_d])
    p.arc(c_d, R_d, math.pi / 2, ang(np.array([ring_r, 0.0]) - c_d))
    p.pts[-1] = np.array([ring_r, 0.0])  # exact (round-off)
    p.line([foot_r, 0.0], sharp=True)          # bearing ring, rim corner
    p.line([foot_r, foot_h], sharp=True)       # square-cut rim edge
    # foot top: straight cone rising to the stem, with a fillet into the stem
    a_in = foot_top_inner - np.array([foot_r, foot_h])
    cf, t1, t2 = fillet_corner(foot_top_inner, a_in, [0.0, 1.0], 0.9)
    p.line(t1, n=2)
    p.arc_to(cf, t2)
    # stem up to the fillet into the bowl
    cf2, t_line, t_circ = fillet_line_circle(stem_r, bowl_c, bowl_R, 0.8)
    p.line(t_line, n=2)
    p.arc_to(cf2, t_circ)
    # outer bowl: sphere up to the widest point, then the upper arc to the rim
    p.arc(bowl_c, bowl_R, ang(t_circ - bowl_c), 0.0)
    phi = math.asin((top_z - up_c[1]) / up_R)
    p.arc(up_c, up_R, 0.0, phi)
    # rim: half circle joining outer and inner wall (concentric with them)
    u = np.array([math.cos(phi), math.sin(phi)])
    p.arc(up_c + (up_R - t / 2) * u, t / 2, phi, phi + math.pi, step_deg=RIM_STEP)
    # inner wall back down: concentric arcs, radius reduced by t
    p.arc(up_c, up_R - t, phi, 0.0)
    p.arc(bowl_c, bowl_R - t, 0.0, -math.pi / 2)
    return p


def sundae_cup():
    """Sundae cup, 12.8 tall: foot with square-cut rim, short stem, a wide
    shallow bowl (flat centre, torus-like sides) whose lip flares outwards,
    0.25 wall, round rim bead."""
    t = 0.25
    foot_r, foot_h = 3.6, 0.3
    ring_r, dome = 3.2, 0.15
    stem_r = 0.5
    bottom_z = 6.8                # underside of the bowl's flat centre
    side_c = np.array([2.2, 11.3])  # centre of the bowl side arc
    side_R = side_c[1] - bottom_z   # 4.5: widest r = 6.7 at z = 11.3
    flare_R = 2.0
    flare_c = np.array([side_c[0] + side_R + flare_R, side_c[1]])
    flare_deg = 38.0
    foot_top_inner = np.array([stem_r, 0.7])

    p = Profile([0.0, dome], step_deg=7.5)
    R_d = (ring_r ** 2 + dome ** 2) / (2 * dome)
    c_d = np.array([0.0, dome - R_d])
    p.arc(c_d, R_d, math.pi / 2, ang(np.array([ring_r, 0.0]) - c_d))
    p.pts[-1] = np.array([ring_r, 0.0])
    p.line([foot_r, 0.0], sharp=True)
    p.line([foot_r, foot_h], sharp=True)
    a_in = foot_top_inner - np.array([foot_r, foot_h])
    cf, t1, t2 = fillet_corner(foot_top_inner, a_in, [0.0, 1.0], 0.8)
    p.line(t1, n=2)
    p.arc_to(cf, t2)
    # stem to the bowl's flat underside, fillet in the corner
    corner = np.array([stem_r, bottom_z])
    cf2, t1, t2 = fillet_corner(corner, [0.0, 1.0], [1.0, 0.0], 0.7)
    p.line(t1)
    p.arc_to(cf2, t2)
    p.line([side_c[0], bottom_z])
    # bowl side: quarter circle up to the widest point, then outward flare
    p.arc(side_c, side_R, -math.pi / 2, 0.0)
    fl = math.radians(flare_deg)
    p.arc(flare_c, flare_R, math.pi, math.pi - fl)
    # rim: half circle concentric with the flare arc
    u = np.array([math.cos(math.pi - fl), math.sin(math.pi - fl)])
    p.arc(flare_c + (flare_R + t / 2) * u, t / 2, -fl, -fl + math.pi, step_deg=RIM_STEP)
    # inner wall (concentric): flare radius + t, side radius - t, flat floor
    p.arc(flare_c, flare_R + t, math.pi - fl, math.pi)
    p.arc(side_c, side_R - t, 0.0, -math.pi / 2)
    p.line([0.0, bottom_z + t], n=2)
    return p


def brandy_bottle():
    """Brandy bottle, 19.0 tall, closed (outer and inner surface): domed punt
    with a thick base, cylindrical body r = 4.5, rounded shoulder, concave
    neck fillet, neck r = 1.3 with a round bead, lip cut flat (two sharp
    corners), bore r = 1.0, wall 0.3."""
    t = 0.3
    body_r = 4.5
    punt = 0.9                     # height of the punt (outer base) on the axis
    base = 0.9                     # extra thickness of the base over the punt
    heel_R = 1.0
    heel_c = np.array([body_r - heel_R, heel_R])        # lowest point at z = 0
    # punt dome: centred on the axis, externally tangent to the heel circle
    ddz = heel_c[1] - punt
    dome_R = (heel_c[0] ** 2 + ddz ** 2 - heel_R ** 2) / (2 * (heel_R - ddz))
    dome_c = np.array([0.0, punt - dome_R])
    body_top = 11.0
    sh_R = 3.0
    sh_c = np.array([body_r - sh_R, body_top])
    neck_r = 1.3
    nf_R = 1.2                     # concave fillet shoulder -> neck
    nf_cx = neck_r + nf_R
    nf_c = np.array([nf_cx, sh_c[1] + math.sqrt((sh_R + nf_R) ** 2 - (nf_cx - sh_c[0]) ** 2)])
    # lip: concave fillet f off the neck into a bead circle, flat top at lip_z
    bead_c, bead_R = np.array([1.25, 18.7]), 0.4
    lip_f = 0.2
    lip_z = 19.0
    bore_r = neck_r - t

    p = Profile([0.0, punt], step_deg=12.0)
    # outer punt dome down to the heel
    u = (heel_c - dome_c) / np.linalg.norm(heel_c - dome_c)
    tp = dome_c + dome_R * u
    p.arc(dome_c, dome_R, math.pi / 2, ang(tp - dome_c))
    a_tp = ang(tp - heel_c) % (2 * math.pi)
    p.arc(heel_c, heel_R, a_tp, 1.5 * math.pi)     # down to the lowest point
    p.pts[-1] = np.array([heel_c[0], 0.0])         # exactly z = 0
    p.arc(heel_c, heel_R, 1.5 * math.pi, 2 * math.pi)
    p.pts[-1] = np.array([body_r, heel_c[1]])
    p.line([body_r, body_top], n=2)
    # shoulder, concave neck fillet, neck
    v = (nf_c - sh_c) / np.linalg.norm(nf_c - sh_c)
    p.arc(sh_c, sh_R, 0.0, ang(v))
    p.arc_to(nf_c, [neck_r, nf_c[1]])
    cf, t_line, t_circ = fillet_line_circle(neck_r, bead_c, bead_R, lip_f)
    p.line(t_line, n=2)
    p.arc_to(cf, t_circ)
    top = math.asin((lip_z - bead_c[1]) / bead_R)
    p.arc(bead_c, bead_R, ang(t_circ - bead_c), top, sharp=True)  # lip corner
    p.line([bore_r, lip_z], sharp=True)                    # flat lip
    # inner wall back down (concentric with the outer one)
    p.line([bore_r, nf_c[1]], n=2)
    p.arc_to(nf_c, nf_c - (nf_R + t) * v)
    p.arc(sh_c, sh_R - t, ang(v), 0.0)
    # inner body down to the inner heel, then the inner base (thick)
    ih_R = 0.7
    ih_cx = body_r - t - ih_R
    idome_R = dome_R + base
    ih_c = np.array([ih_cx, dome_c[1] + math.sqrt((idome_R + ih_R) ** 2 - ih_cx ** 2)])
    p.line([body_r - t, ih_c[1]], n=2)
    w = (ih_c - dome_c) / np.linalg.norm(ih_c - dome_c)
    p.arc(ih_c, ih_R, 0.0, ang(-w))
    p.arc(dome_c, idome_R, ang(w), math.pi / 2)
    return p


OBJECTS = {
    "wine_glass": wine_glass,
    "sundae_cup": sundae_cup,
    "brandy_bottle": brandy_bottle,
}


def build(name):
    pts, sharp = OBJECTS[name]().arrays()
    pts, sharp = orient_clockwise(pts, sharp)
    return pts, sharp


def to_csv(name, pts, sharp):
    doc = (OBJECTS[name].__doc__ or "").strip().splitlines()
    lines = [f"# {name}: profile of a solid of revolution about the local +z axis",
             "# generated by scripts/make_profiles.py -- do not edit by hand"]
    lines += ["# " + s.strip() for s in doc]
    lines += [f"# {len(pts)} points, clockwise (glass on the right), both ends on the axis",
              "r,z,sharp"]
    lines += [f"{r:.6f},{z:.6f},{s}" for (r, z), s in zip(pts, sharp, strict=True)]
    return "\n".join(lines) + "\n"


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--check", action="store_true", help="check only, write nothing")
    ap.add_argument("--out", type=Path, default=SCENES, help="output folder")
    args = ap.parse_args()
    for name in OBJECTS:
        pts, sharp = build(name)
        turn = check_profile(name, pts, sharp)
        smooth_turn = turn[sharp[1:-1] == 0]
        print(f"{name}: {len(pts)} points, r <= {pts[:, 0].max():.3f}, "
              f"z in [{pts[:, 1].min():.3f}, {pts[:, 1].max():.3f}], "
              f"sharp at {np.flatnonzero(sharp).tolist()}, "
              f"max turn at smooth vertices {smooth_turn.max():.1f} deg")
        if not args.check:
            args.out.mkdir(parents=True, exist_ok=True)
            (args.out / f"{name}.csv").write_text(to_csv(name, pts, sharp))


if __name__ == "__main__":
    main()
