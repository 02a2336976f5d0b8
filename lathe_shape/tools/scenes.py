"""Scene files: loading with defines and resolution overrides (clear errors
that name the file), and the edits the tools make to scene XML text."""

from __future__ import annotations

import os
import xml.etree.ElementTree as ET

import mitsuba as mi

__all__ = [
    "SceneError",
    "integrator_name",
    "lathe_ids",
    "load_scene",
    "load_string_in",
    "points_text",
    "replace_profile",
    "scene_integrator",
    "set_defaults",
    "set_film_size",
]


class SceneError(RuntimeError):
    """A scene could not be loaded; the message names the file and the cause."""


def _parse_xml(xml_text: str, source: str) -> ET.Element:
    try:
        return ET.fromstring(xml_text)
    except ET.ParseError as e:
        raise SceneError(f"{source}: not a valid XML file ({e})") from None


def _lathe_elements(root: ET.Element) -> list[ET.Element]:
    """The ``<shape type="lathe">`` elements, in document order."""
    return [e for e in root.iter("shape") if e.get("type") == "lathe"]


def lathe_ids(xml_text: str, source: str = "scene") -> list[str]:
    """Ids of the scene's ``<shape type="lathe">`` elements in document
    order (``""`` for one without id)."""
    return [e.get("id", "") for e in _lathe_elements(_parse_xml(xml_text, source))]


def set_film_size(xml_text: str, size: tuple[int, int], source: str = "scene") -> str:
    """The scene text with every sensor's film set to ``size`` = (width,
    height) pixels."""
    root = _parse_xml(xml_text, source)
    films = root.findall(".//sensor/film")
    if not films:
        raise SceneError(f"{source}: no <sensor> with a <film> to set the resolution on")
    for film in films:
        for name, value in zip(("width", "height"), size, strict=True):
            node = next((c for c in film if c.get("name") == name), None)
            if node is None:
                node = ET.SubElement(film, "integer", {"name": name})
            node.tag = "integer"
            node.set("value", str(value))
    return ET.tostring(root, encoding="unicode")


def set_defaults(xml_text: str, source: str = "scene", **values: object) -> str:
    """The scene text with the value of each named ``<default>`` replaced
    (e.g. ``set_defaults(text, spp=16, mesh_segments=64)``); a name the
    scene does not declare is added as a new ``<default>``."""
    root = _parse_xml(xml_text, source)
    for name, value in values.items():
        node = next((d for d in root.findall("default") if d.get("name") == name), None)
        if node is None:
            node = ET.Element("default", {"name": name})
            root.insert(0, node)
        node.set("value", str(value))
    return ET.tostring(root, encoding="unicode")


def points_text(points) -> str:
    """(n, 2) points -> the inline ``"r z, r z, ..."`` profile string."""
    return ", ".join(f"{r:.9g} {z:.9g}" for r, z in points)


def replace_profile(
    xml_text: str,
    points=None,
    filename: str | None = None,
    kind: str = "polyline",
    lathe_id: str | None = None,
    source: str = "scene",
) -> str:
    """The scene text with a lathe's profile replaced: by the inline
    ``points`` ((n, 2) array) or by the profile file ``filename`` (exactly
    one), of the given ``kind``. ``lathe_id`` picks the lathe (default: the
    first ``<shape type="lathe">``)."""
    if (points is None) == (filename is None):
        raise ValueError("replace_profile: give exactly one of points and filename")
    root = _parse_xml(xml_text, source)
    lathes = _lathe_elements(root)
    if lathe_id is not None:
        lathes = [e for e in lathes if e.get("id") == lathe_id]
    if not lathes:
        which = f" with id '{lathe_id}'" if lathe_id is not None else ""
        raise SceneError(f"{source}: no <shape type=\"lathe\">{which}")
    lathe = lathes[0]
    for child in [c for c in lathe if c.get("name") in ("filename", "profile", "kind")]:
        lathe.remove(child)
    name, value = ("profile", points_text(points)) if filename is None else ("filename", filename)
    lathe.insert(0, ET.Element("string", {"name": "kind", "value": kind}))
    lathe.insert(0, ET.Element("string", {"name": name, "value": value}))
    return ET.tostring(root, encoding="unicode")


def scene_integrator(scene: mi.Scene) -> mi.Integrator:
    """The scene's integrator, or stock ``path`` (like Mitsuba's own CLI)
    when the scene names none."""
    integrator = scene.integrator()
    return integrator if integrator is not None else mi.load_dict({"type": "path"})


def integrator_name(integrator: mi.Integrator) -> str:
    """``PathIntegrator`` for Mitsuba's own integrators; the Python class name
    (``LathePathIntegrator``) for Python ones, whose ``class_name()`` is
    only their C++ base class (``SamplingIntegrator``)."""
    cls = type(integrator)
    if cls.__module__.split(".")[0] != "mitsuba":
        return cls.__name__
    return integrator.class_name()


def load_string_in(folder: str | os.PathLike, text: str, **defines: str) -> mi.Scene:
    """``mi.load_string`` with relative file names (profiles, textures)
    resolved in ``folder``, as if ``text`` were a file there."""
    resolver = mi.file_resolver()
    saved = mi.FileResolver(resolver)
    resolver.prepend(os.path.abspath(os.fspath(folder)))
    try:
        return mi.load_string(text, **defines)
    finally:
        mi.set_file_resolver(saved)


def _without_traceback(message: str) -> str:
    """Mitsuba embeds a Python plugin's traceback in its error; keep the
    location line and the exception's own line."""
    head, sep, tail = message.partition("Traceback (most recent call last):")
    if not sep:
        return message
    last = [line for line in tail.splitlines() if line.strip()][-1:]
    return head.rstrip() + ("\n  " + last[0].strip() if last else "")


def load_scene(
    path: str | os.PathLike,
    defines: dict[str, str] | None = None,
    resolution: tuple[int, int] | None = None,
) -> mi.Scene:
    """Load a Mitsuba XML scene (after ``import lathe_shape`` registered the
    plugins), optionally overriding the film resolution."""
    path = os.fspath(path)
    if os.path.isdir(path):
        raise SceneError(f"'{path}' is a folder, not a scene file")
    if not os.path.isfile(path):
        raise SceneError(f"scene file '{path}' not found")
    defines = dict(defines or {})
    try:
        if resolution is None:
            scene = mi.load_file(path, **defines)
        else:
            with open(path, encoding="utf-8") as f:
                text = set_film_size(f.read(), resolution, path)
            scene = load_string_in(os.path.dirname(os.path.abspath(path)), text, **defines)
    except SceneError:
        raise
    except Exception as e:  # Mitsuba reports parse/plugin errors as RuntimeError
        # With a resolution override Mitsuba parsed a string: name the file.
        message = _without_traceback(str(e)).replace("At string (", f"At {path} (")
        message = message.replace("While loading string (", f"While loading {path} (")
        raise SceneError(f"{path}: could not load the scene:\n{message}") from None
    if not isinstance(scene, mi.Scene):
        raise SceneError(f"{path}: the file does not describe a <scene>")
    return scene
