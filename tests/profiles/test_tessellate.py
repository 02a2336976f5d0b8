"""Reference tessellation: watertight, outward, normals equal the profile's."""

from __future__ import annotations

import math

import numpy as np
import pytest
from conftest import SCENES, assert_watertight, random_ring_profile, random_vase_profile

from lathe_shape.profiles.polyline import make_profile, read_profile_csv
from lathe_shape.profiles.sources import read_profile_options
from lathe_shape.tessellate import tessellate_profile


def revolved_volume(pts: np.ndarray, steps: int) -> float:
    """Volume of the polygon revolved through a regular ``steps``-gon
    (Pappus with the polygon's r scaled by the n-gon's area factor)."""
    r, z = pts[:, 0], pts[:, 1]
    r1, z1 = np.roll(r, -1), np.roll(z, -1)
    # Exact integral of pi r^2 dz over each edge, times the n-gon factor.
    vol = -np.pi * np.sum((z1 - z) * (r * r + r * r1 + r1 * r1) / 3.0)
    return abs(vol) * (steps * math.sin(2 * math.pi / steps) / (2 * math.pi))


def mesh_volume(mesh) -> float:
    v = mesh.positions[mesh.faces]
    return float(np.einsum("ij,ij->i", v[:, 0], np.cross(v[:, 1], v[:, 2])).sum() / 6.0)


@pytest.mark.parametrize("csv", sorted(SCENES.glob("*.csv")), ids=lambda p: p.stem)
def test_scene_profiles_watertight(csv):
    if read_profile_options(csv).get("open"):
        pytest.skip("an open sheet (# open: true) has no inside (test_shape renders its scene)")
    pts, sharp, labels = read_profile_csv(csv)
    prof = make_profile(pts, sharp, labels, source=str(csv))
    mesh = tessellate_profile(prof, 64)
    assert_watertight(mesh)
    assert mesh_volume(mesh) == pytest.approx(revolved_volume(prof.points, 64), rel=1e-9)


@pytest.mark.parametrize("seed", range(20))
def test_random_profiles_watertight(seed):
    rng = np.random.default_rng(100 + seed)
    raw = random_ring_profile(rng, 9) if seed % 2 else random_vase_profile(rng, 8)
    prof = make_profile(raw, rng.uniform(size=len(raw)) < 0.3, crease_angle=rng.uniform(5, 90))
    steps = int(rng.integers(3, 40))
    mesh = tessellate_profile(prof, steps)
    assert_watertight(mesh)
    # Positive volume = faces wound outward; and it is the right volume.
    assert mesh_volume(mesh) == pytest.approx(revolved_volume(prof.points, steps), rel=1e-9)


@pytest.mark.parametrize("seed", range(6))
def test_vertex_normals_are_profile_normals(seed):
    rng = np.random.default_rng(200 + seed)
    raw = random_ring_profile(rng, 10) if seed % 2 else random_vase_profile(rng, 8)
    prof = make_profile(raw, crease_angle=25.0)
    steps = 16
    mesh = tessellate_profile(prof, steps)
    np.testing.assert_allclose(np.linalg.norm(mesh.normals, axis=1), 1.0, atol=1e-12)
    # Every triangle corner's normal, rotated back into the (r, z) plane at
    # its azimuth, is the shading normal that its segment has at that end.
    v = mesh.positions[mesh.faces]  # (F, 3, 3)
    n = mesh.normals[mesh.faces]
    centroid = v.mean(axis=1)
    phi_c = np.arctan2(centroid[:, 1], centroid[:, 0])
    p0, p1 = prof.segment_points()
    for f in range(len(mesh.faces)):
        r_c = np.hypot(*centroid[f, :2]) / math.cos(math.pi / steps)  # on a chord
        rz = np.array([np.hypot(*v[f, k, :2]) for k in range(3)])
        zs = v[f, :, 2]
        # Which segment: both of the face's distinct (r, z) corners lie on it.
        corners = np.unique(np.round(np.stack([rz, zs], axis=1), 12), axis=0)
        seg = None
        for s in range(prof.segment_count):
            d = p1[s] - p0[s]
            ok = True
            for c in corners:
                w = c - p0[s]
                t = (w @ d) / (d @ d)
                ok &= abs(d[0] * w[1] - d[1] * w[0]) <= 1e-9 and -1e-9 <= t <= 1 + 1e-9
            if ok:
                seg = s
                break
        assert seg is not None, r_c
        for k in range(3):
            at_start = np.allclose([rz[k], zs[k]], p0[seg], atol=1e-12)
            expected = prof.normal_start[seg] if at_start else prof.normal_end[seg]
            phi = math.atan2(v[f, k, 1], v[f, k, 0]) if rz[k] > 0 else phi_c[f]
            n3 = np.array([expected[0] * math.cos(phi), expected[0] * math.sin(phi), expected[1]])
            if rz[k] == 0.0:
                # Pole copies carry the normal at the wedge's middle azimuth.
                np.testing.assert_allclose(n[f, k], n3, atol=1e-9)
            else:
                np.testing.assert_allclose(n[f, k], n3, atol=1e-12)


def test_flat_normals_when_not_smooth():
    prof = make_profile(np.array([[0, 0], [1, 0], [1.2, 1], [0.8, 2], [0, 2]], float))
    mesh = tessellate_profile(prof, 8, smooth=False)
    assert_watertight(mesh)
    # Each face's three corners carry one segment's flat normal: the same z
    # component, which is one of the segments' geometric normals.
    nz = mesh.normals[mesh.faces, 2]
    np.testing.assert_allclose(nz, nz[:, :1].repeat(3, axis=1), atol=1e-12)
    seg_nz = prof.segment_normals()[:, 1]
    assert np.abs(nz[:, :1] - seg_nz[None, :]).min(axis=1).max() < 1e-12


#: The cup of polyline "0 0, 1 0, 1 2, 0.9 2, 0.9 0.1, 0 0.1" written as
#: straight Bezier segments (joints given twice): its corners are C0 joints.
BEZIER_CUP = ("0 0, 0.333333 0, 0.666667 0, 1 0, 1 0, 1 0.666667, 1 1.33333, 1 2, 1 2, 0.966667 2, "
              "0.933333 2, 0.9 2, 0.9 2, 0.9 1.36667, 0.9 0.733333, 0.9 0.1, 0.9 0.1, 0.6 0.1, 0.3 0.1, "
              "0 0.1")


@pytest.mark.parametrize("kind, profile", [("bezier", BEZIER_CUP),
                                           ("sor", "0.2 -0.5, 1 0, 1.2 0.6, 0.6 1.5, 0.5 2.5, 0.6 3")])
def test_curve_corners_get_two_rings(kind, profile):
    """A curve kind's corner had one ring, with the next segment's normal:
    the straight wall above the cup's bottom corner was shaded with the
    bottom's normal at its foot (black bands on the reference mesh, mean
    0.774 where the exact render reads 0.831). Every band's vertex normals
    now agree with its faces' normals, and the mesh stays watertight."""
    import mitsuba as mi

    lathe = mi.load_dict({"type": "lathe", "profile": profile, "kind": kind, "mesh_segments": 16})
    mesh = lathe.surface.tessellate(16)
    vertices, normals, faces = mesh.positions, mesh.normals, mesh.faces.astype(np.int64)
    face_normal = np.cross(vertices[faces[:, 1]] - vertices[faces[:, 0]],
                           vertices[faces[:, 2]] - vertices[faces[:, 0]])
    area = np.linalg.norm(face_normal, axis=1)
    face_normal = face_normal[area > 0] / area[area > 0, None]
    for corner in range(3):
        agree = np.einsum("ij,ij->i", normals[faces[area > 0, corner]], face_normal)
        assert agree.min() > 0.3, (kind, agree.min())
    assert_watertight(mesh)
