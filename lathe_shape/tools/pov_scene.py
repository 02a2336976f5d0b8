"""A complete Mitsuba scene for the lathes and sors imported from a POV-Ray
scene (``lathe-profile --from-pov FILE.pov --scene OUT.xml``), renderable as
is with ``lathe-render OUT.xml``.

What it holds: ``<scene version="3.0.0">`` with defaults ``spp``, ``res``
and ``integrator`` (``lathe_path``, as the project's scenes); a perspective
camera framing every placed object from the front (-y), above; a soft
constant sky and a directional light; a grey floor under the lowest object;
every placement of every object as a ``<shape type="lathe">`` with its
profile CSV (relative to the scene file) and ``to_world``. Materials, from
what the POV-Ray scene says literally (or through declared textures): an
``interior { ior }`` gives a ``dielectric`` (``thindielectric`` for an open
sheet), ``finish { metallic }`` or a ``reflection`` of at least 0.5 a
``conductor`` tinted by the pigment, a smaller ``reflection`` a ``plastic``
with the pigment as diffuse colour, a pigment alone a ``diffuse``; else a
neutral grey ``diffuse`` (all but the dielectrics two-sided on an open
sheet). Nothing else of the POV-Ray scene (its camera,
lights, other objects) is carried over.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field

import numpy as np

__all__ = ["SceneShape", "scene_xml", "material_xml"]


@dataclass
class SceneShape:
    """One imported profile and where it is placed."""

    id: str
    csv: str
    kind: str
    open_sheet: bool
    #: Mitsuba ``to_world`` matrices (4x4), one per placement.
    to_worlds: list[np.ndarray]
    #: (n, 2) profile points (r, z), for the framing.
    points: np.ndarray
    material: object | None = None
    comment: str = ""
    extra: list[str] = field(default_factory=list)


def material_xml(material, open_sheet: bool, indent: str = "        ") -> str:
    """The ``<bsdf>`` of a :class:`~lathe_shape.profiles.pov_sdl.Material`
    (module docstring)."""
    def rgb(c) -> str:
        c = np.clip(np.asarray(c, dtype=np.float64)[:3], 0.0, 1.0)
        return ", ".join(f"{v:.4g}" for v in c)

    color = getattr(material, "color", None)
    if material is not None and material.ior is not None and material.ior > 0:
        kind = "thindielectric" if open_sheet else "dielectric"
        return (f'{indent}<bsdf type="{kind}">\n'
                f'{indent}    <float name="int_ior" value="{material.ior:.6g}"/>\n'
                f'{indent}    <float name="ext_ior" value="1.0"/>\n{indent}</bsdf>\n')
    if open_sheet:  # both sides of a single sheet are seen
        inner = material_xml(material, False, indent + "    ")
        return f'{indent}<bsdf type="twosided">\n{inner}{indent}</bsdf>\n'
    reflection = getattr(material, "reflection", None) or 0.0
    if material is not None and (material.metallic or reflection >= 0.5):
        tint = rgb(color) if color is not None and material.metallic else rgb([max(reflection, 0.6)] * 3)
        return (f'{indent}<bsdf type="conductor">\n{indent}    <rgb name="specular_reflectance" '
                f'value="{tint}"/>\n{indent}</bsdf>\n')
    diffuse = rgb(color) if color is not None else "0.6, 0.6, 0.6"
    if reflection > 0:
        return (f'{indent}<bsdf type="plastic">\n{indent}    <rgb name="diffuse_reflectance" '
                f'value="{diffuse}"/>\n{indent}</bsdf>\n')
    return (f'{indent}<bsdf type="diffuse">\n{indent}    <rgb name="reflectance" value="{diffuse}"/>\n'
            f'{indent}</bsdf>\n')


def _bounds(shapes: list[SceneShape]) -> tuple[np.ndarray, np.ndarray]:
    """World box of every placement (the box of each revolved profile's
    local bounding cylinder, transformed)."""
    corners = []
    for s in shapes:
        p = np.asarray(s.points, dtype=np.float64)
        r = float(np.abs(p[:, 0]).max())
        lo, hi = float(p[:, 1].min()), float(p[:, 1].max())
        local = np.array([[sx * r, sy * r, z, 1.0] for sx in (-1, 1) for sy in (-1, 1) for z in (lo, hi)])
        for m in s.to_worlds:
            corners.append((np.asarray(m) @ local.T).T[:, :3])
    pts = np.concatenate(corners)
    return pts.min(axis=0), pts.max(axis=0)


def scene_xml(shapes: list[SceneShape], source: str, fov: float = 35.0, scene_file: str = "scene.xml") -> str:
    """The scene (module docstring) for ``shapes``; ``source`` names the
    POV-Ray file in a comment, ``scene_file`` the scene's own in the
    command that renders it."""
    lo, hi = _bounds(shapes)
    center = 0.5 * (lo + hi)
    radius = max(float(np.linalg.norm(hi - lo)) / 2, 1e-6)
    direction = np.array([0.35, -1.0, 0.45])
    direction /= np.linalg.norm(direction)
    distance = 1.15 * radius / math.sin(math.radians(fov) / 2)
    origin = center + distance * direction
    floor_z = lo[2] - 1e-3 * radius

    def v(a) -> str:
        return ", ".join(f"{x:.6g}" for x in a)

    out = [f"<!-- Imported from the POV-Ray scene {source} by lathe-profile --from-pov --scene.\n"
           f"     POV-Ray (x, y, z) is Mitsuba (x, z, y): z is up here. Only the lathe and sor\n"
           f"     objects are imported; the camera, light and floor are this importer's.\n\n"
           f"     lathe-render {scene_file} -D spp=64 -D res=512 -->\n",
           '<scene version="3.0.0">\n',
           '    <default name="spp" value="64"/>\n',
           '    <default name="res" value="256"/>\n',
           '    <default name="max_depth" value="12"/>\n',
           '    <default name="integrator" value="lathe_path"/>\n\n',
           '    <integrator type="$integrator">\n        <integer name="max_depth" value="$max_depth"/>\n'
           '    </integrator>\n\n',
           f'    <sensor type="perspective">\n        <float name="fov" value="{fov:g}"/>\n'
           f'        <string name="fov_axis" value="smaller"/>\n'
           f'        <float name="far_clip" value="{100 * (distance + radius):.6g}"/>\n'
           f'        <float name="near_clip" value="{1e-3 * radius:.6g}"/>\n'
           f'        <transform name="to_world">\n'
           f'            <lookat origin="{v(origin)}" target="{v(center)}" up="0, 0, 1"/>\n'
           f'        </transform>\n'
           f'        <sampler type="independent">\n            <integer name="sample_count" value="$spp"/>\n'
           f'        </sampler>\n'
           f'        <film type="hdrfilm">\n            <integer name="width" value="$res"/>\n'
           f'            <integer name="height" value="$res"/>\n        </film>\n    </sensor>\n\n',
           '    <emitter type="constant">\n        <rgb name="radiance" value="0.35, 0.35, 0.35"/>\n'
           '    </emitter>\n',
           '    <emitter type="directional">\n        <vector name="direction" value="0.4, 0.7, -1"/>\n'
           '        <rgb name="irradiance" value="2.5, 2.5, 2.5"/>\n    </emitter>\n\n',
           f'    <shape type="rectangle" id="floor">\n        <transform name="to_world">\n'
           f'            <scale x="{20 * radius:.6g}" y="{20 * radius:.6g}" z="1"/>\n'
           f'            <translate x="{center[0]:.6g}" y="{center[1]:.6g}" z="{floor_z:.6g}"/>\n'
           f'        </transform>\n        <bsdf type="diffuse">\n'
           f'            <rgb name="reflectance" value="0.45, 0.45, 0.45"/>\n        </bsdf>\n    </shape>\n']
    for s in shapes:
        bsdf = material_xml(s.material, s.open_sheet)
        if s.comment:
            out.append(f"\n    <!-- {s.comment} -->\n")
        for k, m in enumerate(s.to_worlds):
            sid = s.id if k == 0 else f"{s.id}__{k + 1}"
            matrix = " ".join(f"{x:.9g}" for x in np.asarray(m).ravel())
            out.append(f'    <shape type="lathe" id="{sid}">\n'
                       f'        <string name="filename" value="{s.csv}"/>\n'
                       f'        <string name="kind" value="{s.kind}"/>\n'
                       f'        <boolean name="open" value="{str(s.open_sheet).lower()}"/>\n'
                       f'        <transform name="to_world">\n            <matrix value="{matrix}"/>\n'
                       f'        </transform>\n{bsdf}    </shape>\n')
    out.append("</scene>\n")
    return "".join(out)


def relative_csv(csv: str, scene_path: str) -> str:
    """The CSV's path as the scene file refers to it."""
    return os.path.relpath(os.path.abspath(csv), os.path.dirname(os.path.abspath(scene_path)) or ".")
