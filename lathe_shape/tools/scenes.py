"""Scene files: loading with defines and resolution overrides (clear errors
that name the file), and the edits the tools make to scene XML text."""

from __future__ import annotations

import os
import re
import xml.etree.ElementTree as ET
from collections.abc import Callable
from xml.parsers import expat

import mitsuba as mi

__all__ = [
    "SceneError",
    "SceneSyntaxError",
    "blank_comments",
    "check_affine_matrices",
    "integrator_name",
    "lathe_ids",
    "load_scene",
    "load_string_in",
    "read_scene_text",
    "points_text",
    "replace_profile",
    "scene_integrator",
    "set_film_size",
    "set_mesh_segments",
]


class SceneError(RuntimeError):
    """A scene could not be loaded; the message names the file and the cause."""


class SceneSyntaxError(SceneError):
    """The scene text is not well-formed XML."""


def _parse_xml(xml_text: str, source: str) -> ET.Element:
    try:
        return ET.fromstring(blank_comments(xml_text.encode("utf-8")).decode("utf-8"))
    except ET.ParseError as e:
        raise SceneSyntaxError(f"{source}: not a valid XML file ({e})") from None


def _lathe_elements(root: ET.Element) -> list[ET.Element]:
    """The ``<shape type="lathe">`` elements, in document order."""
    return [e for e in root.iter("shape") if e.get("type") == "lathe"]


def lathe_ids(xml_text: str, source: str = "scene") -> list[str]:
    """Ids of the scene's ``<shape type="lathe">`` elements in document
    order (``""`` for one without id)."""
    return [e.get("id", "") for e in _lathe_elements(_parse_xml(xml_text, source))]


#: The start tag of an XML element (attribute values may contain ``>``).
_START_TAG = re.compile(rb"""<([^\s/>]+)(?:\s+[^\s=/>]+\s*=\s*(?:"[^"]*"|'[^']*'))*\s*(/?)>""")


def blank_comments(data: bytes) -> bytes:
    """``data`` with the text of every XML comment replaced by spaces (line
    breaks kept, so every offset, line and column stays the same).

    Mitsuba's XML parser accepts comments that strict XML refuses, such as
    one quoting a command line (``--option`` holds a ``--``); the parsers
    that edit scene files here are strict, so they read the scene this way."""
    return re.sub(rb"<!--(.*?)-->", lambda m: b"<!--" + re.sub(rb"[^\n]", b" ", m.group(1)) + b"-->",
                  data, flags=re.S)


def _elements(data: bytes, source: str, wanted: Callable[[str, dict[str, str], str], bool],
              children: tuple[str, ...]) -> list[tuple[int, dict[str, int]]]:
    """Where the elements of the UTF-8 scene text ``data`` are for which
    ``wanted(name, attributes, parent name)`` holds: for each, the byte
    offset of its start tag and those of its direct children whose ``name``
    attribute is one of ``children`` (by that name, the first of each)."""
    data = blank_comments(data)
    parser = expat.ParserCreate()
    found: list[tuple[int, dict[str, int]]] = []
    path: list[tuple[str, int]] = []  # the open elements, outermost first: (name, index in found or -1)

    def start(name: str, attributes: dict[str, str]) -> None:
        parent, owner = path[-1] if path else ("", -1)
        if owner >= 0 and attributes.get("name") in children:
            found[owner][1].setdefault(attributes["name"], parser.CurrentByteIndex)
        index = -1
        if wanted(name, attributes, parent):
            found.append((parser.CurrentByteIndex, {}))
            index = len(found) - 1
        path.append((name, index))

    parser.StartElementHandler = start
    parser.EndElementHandler = lambda name: path.pop()
    try:
        parser.Parse(data, True)
    except expat.ExpatError as e:
        raise SceneSyntaxError(f"{source}: not a valid XML file ({e})") from None
    return found


def check_affine_matrices(xml_text: str, source: str = "scene",
                          defines: dict[str, str] | None = None) -> None:
    """Refuse a ``<matrix>`` of 16 values whose bottom row is not ``0 0 0
    1``: Mitsuba's XML parser silently drops that row (a projective
    ``to_world`` renders as an affine one, the lathe's exact surface and
    any mesh alike), so a projective transform is refused here, naming
    ``source``, the line, the element it belongs to and its parameter
    (issue 24, item 15). ``$name`` references take their ``defines``;
    values that are not numbers then are left to Mitsuba. Text that is
    not well-formed XML is left to Mitsuba too."""
    data = blank_comments(xml_text.encode("utf-8"))
    parser = expat.ParserCreate()
    path: list[tuple[str, dict[str, str]]] = []  # the open elements, outermost first
    found: list[str] = []

    def owner() -> str:
        for name, attributes in reversed(path):
            if "type" in attributes and name != "transform":
                ident = attributes.get("id")
                return f"{attributes['type']} '{ident}'" if ident else f"a {attributes['type']} {name}"
        return "the scene"

    def start(name: str, attributes: dict[str, str]) -> None:
        if name == "matrix" and not found:
            text = attributes.get("value", "")
            for key, value in (defines or {}).items():
                text = re.sub(rf"\${re.escape(key)}(?!\w)", lambda _m, v=value: v, text)
            try:
                values = [float(v) for v in text.replace(",", " ").split()]
            except ValueError:
                values = []
            if len(values) == 16 and values[12:] != [0.0, 0.0, 0.0, 1.0]:
                transform = path[-1][1].get("name", "") if path and path[-1][0] == "transform" else ""
                row = " ".join(f"{v:g}" for v in values[12:])
                param = f" parameter '{transform}'" if transform else ""
                found.append(f"{source}:{parser.CurrentLineNumber}: {owner()},{param}: the <matrix> "
                             f"is projective (bottom row {row}), which Mitsuba would read as affine "
                             f"(bottom row 0 0 0 1) without a word; only affine transforms are "
                             f"supported")
        path.append((name, attributes))

    parser.StartElementHandler = start
    parser.EndElementHandler = lambda name: path.pop()
    try:
        parser.Parse(data, True)
    except expat.ExpatError:
        return
    if found:
        raise SceneError(found[0])


def _with_value(tag: bytes, value: int) -> bytes:
    """The start tag ``tag`` with its ``value`` attribute set to ``value``."""
    text = f'value="{value}"'.encode()
    edited, count = re.subn(rb"""\bvalue\s*=\s*(?:"[^"]*"|'[^']*')""", text, tag, count=1)
    if count:
        return edited
    end = len(tag) - (2 if tag.endswith(b"/>") else 1)
    return tag[:end].rstrip() + b" " + text + tag[end:]


def _set_integers(data: bytes, elements: list[tuple[int, dict[str, int]]], values: dict[str, int]) -> str:
    """The UTF-8 scene text ``data`` with, in each of ``elements`` (from
    :func:`_elements`), the ``<integer>`` children named in ``values`` set
    to those values; a missing one is added on the line of the element's
    start tag. Every other character, comments and line breaks included,
    stays where it was, so that Mitsuba's errors about the edited text give
    the line and column of the file."""
    edits: list[tuple[int, int, bytes]] = []  # (start, end, replacement) byte ranges
    for element_start, children in elements:
        missing = b""
        for name, value in values.items():
            if name in children:
                tag = _START_TAG.match(data, children[name])
                edits.append((tag.start(), tag.end(), _with_value(tag.group(0), value)))
            else:
                missing += f'<integer name="{name}" value="{value}"/>'.encode()
        tag = _START_TAG.match(data, element_start)
        if missing and tag.group(2):  # <tag .../>: open it, add the values, close it
            edits.append((tag.end() - 2, tag.end(), b">" + missing + b"</" + tag.group(1) + b">"))
        elif missing:
            edits.append((tag.end(), tag.end(), missing))
    for start, end, replacement in sorted(edits, reverse=True):
        data = data[:start] + replacement + data[end:]
    return data.decode("utf-8")


def set_film_size(xml_text: str, size: tuple[int, int], source: str = "scene") -> str:
    """The scene text with every sensor's film set to ``size`` = (width,
    height) pixels: only the films' ``width`` / ``height`` values change
    (see :func:`_set_integers`)."""
    data = xml_text.encode("utf-8")
    films = _elements(data, source, lambda name, _, parent: name == "film" and parent == "sensor",
                      ("width", "height"))
    if not films:
        raise SceneError(f"{source}: no <sensor> with a <film> to set the resolution on")
    return _set_integers(data, films, dict(zip(("width", "height"), size, strict=True)))


def set_mesh_segments(xml_text: str, segments: int, source: str = "scene") -> str:
    """The scene text with every ``<shape type="lathe">``'s
    ``<integer name="mesh_segments">`` set to ``segments`` (added where the
    lathe has none; see :func:`_set_integers`); raises
    :class:`SceneSyntaxError` for text that is not well-formed XML."""
    data = xml_text.encode("utf-8")
    lathes = _elements(data, source, lambda name, attributes, _: name == "shape"
                       and attributes.get("type") == "lathe", ("mesh_segments",))
    return _set_integers(data, lathes, {"mesh_segments": segments})


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


#: Scenes are loaded sequentially (``parallel=False``), for two reasons.
#: Mitsuba's parallel loading registers shapes and BSDFs in whatever order
#: its threads finish, and the traced render kernel (its virtual calls over
#: those objects) follows that order: a new process then often traced
#: another kernel than the ones in Dr.Jit's on-disk cache and compiled it
#: (0.2 s for the bottle). Measured on the sundae cup, 16 processes (4 at a
#: time): 4 distinct render kernels loaded in parallel, 2 sequentially (a
#: variation that remains, and that stock ``path`` shows too). And a thread
#: that waits for Dr.Jit while building one lathe runs the next lathe's
#: construction inside that wait: with hundreds of lathes the nesting grows
#: deep (see ``lathe_shape.RECURSION_LIMIT``). Sequential loading took no
#: longer on the example scenes (45-58 ms each); 1000 wine glasses load in
#: 3.7 s and 430 MB with ``reference proxy``.
PARALLEL_LOAD = False


def load_string_in(folder: str | os.PathLike, text: str, **defines: str) -> mi.Scene:
    """``mi.load_string`` with relative file names (profiles, textures)
    resolved in ``folder``, as if ``text`` were a file there (sequentially,
    see :data:`PARALLEL_LOAD`)."""
    resolver = mi.file_resolver()
    saved = mi.FileResolver(resolver)
    resolver.prepend(os.path.abspath(os.fspath(folder)))
    try:
        return mi.load_string(text, parallel=PARALLEL_LOAD, **defines)
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


def read_scene_text(path: str | os.PathLike) -> str:
    """The text of the scene file ``path``, which must be UTF-8; raises
    :class:`SceneError` naming the file when it is missing, a folder,
    unreadable or not UTF-8 text."""
    path = os.fspath(path)
    if os.path.isdir(path):
        raise SceneError(f"'{path}' is a folder, not a scene file")
    if not os.path.isfile(path):
        raise SceneError(f"scene file '{path}' not found")
    try:
        with open(path, "rb") as f:
            data = f.read()
    except OSError as e:
        raise SceneError(f"cannot read scene file '{path}' ({e.strerror or e})") from None
    try:
        return data.decode("utf-8")
    except UnicodeDecodeError as e:
        line = data.count(b"\n", 0, e.start) + 1
        where = f"byte 0x{data[e.start]:02x} on line {line}"
        raise SceneError(f"{path}: not a UTF-8 text file ({where})") from None


def _mitsuba_message(error: BaseException, path: str) -> str:
    """Mitsuba's error, naming ``path`` where it says it parsed a string."""
    message = _without_traceback(str(error))
    for said in ("loading string (", "At string ("):
        message = message.replace(said, said.replace("string", path))
    return message


#: Mitsuba's source tags in its messages (``[parser.cpp:1718]``, ``[PluginManager]``).
_SOURCE_TAG = re.compile(r"\[[A-Za-z_]+(?:\.(?:cpp|h):\d+)?\]\s*")
#: Where in the file Mitsuba's parser was.
_LOCATION = re.compile(r"(?:At|While loading) (?P<file>.+?) \((?P<position>line \d+, col \d+)\):\s*")
#: An exception's class name before its message (``ProfileError: ...``).
_EXCEPTION_NAME = re.compile(r"^[A-Za-z_.]*(?:Error|Exception):\s*")


def _one_line_load_error(message: str, path: str) -> str:
    """Mitsuba's (multi-line) error on loading the scene ``path`` as one
    line: the file and position it names first, then what went wrong, with
    Mitsuba's source tags, exception class names and list bullets left out
    (``neg.xml (line 5, col 4): failed to instantiate shape plugin of type
    "lathe": neg.csv, line 4: negative radius r = -1 (r must be >= 0)``)."""
    message = _SOURCE_TAG.sub("", message)
    where = f"{path}: could not load the scene"
    found = _LOCATION.search(message)
    if found:
        where = f"{found['file']} ({found['position']})"
        message = message[:found.start()] + message[found.end():]
    text = ""
    for line in message.splitlines():
        part = _EXCEPTION_NAME.sub("", line.strip().removeprefix("- ").strip())
        if part:
            text = part if not text else text + (" " if text.endswith(":") else ", ") + part
    return f"{where}: {text}"


def _unused_defines_message(message: str, path: str, text: str) -> str | None:
    """For Mitsuba's "Found unused parameters" (a ``-D`` name the scene
    does not use): one line naming them and the scene's own parameters."""
    if "Found unused parameters" not in message:
        return None
    unused = re.findall(r"\$(\w+)=", message)
    try:  # (the scene's own <default> elements; none listed for text only Mitsuba's parser reads)
        declared = sorted({e.get("name", "") for e in _parse_xml(text, path).iter("default")} - {""})
    except SceneSyntaxError:
        declared = []
    if unused and all(name in declared for name in unused):
        return (f"{path}: -D {', '.join(unused)}: the scene declares it as a <default> but uses no "
                f"${unused[0]} anywhere")
    listed = ", ".join(declared) if declared else "none"
    return (f"{path}: -D {', '.join(unused)}: the scene uses no such parameter (its <default> "
            f"parameters: {listed})")


def _still_used(defines: dict[str, str], text: str, edited: str) -> dict[str, str]:
    """``defines`` less those that only the film sizes :func:`set_film_size`
    replaced in ``text`` referred to (``-D res=...`` with a resolution
    override), which Mitsuba would report as unused."""
    def used(name: str, xml_text: str) -> bool:
        return re.search(rf"\${re.escape(name)}(?!\w)", xml_text) is not None

    return {k: v for k, v in defines.items() if used(k, edited) or not used(k, text)}


def load_scene(
    path: str | os.PathLike,
    defines: dict[str, str] | None = None,
    resolution: tuple[int, int] | None = None,
    edit: Callable[[str, str], str] | None = None,
) -> mi.Scene:
    """Load a Mitsuba XML scene (after ``import lathe_shape`` registered the
    plugins), optionally edited by ``edit(text, path)`` (e.g. the box filters
    of denoised turntables) and with the film resolution overridden.

    Errors name ``path`` and the line and column in it, with or without
    ``resolution``: the override edits only the films' sizes (see
    :func:`set_film_size`), and a file that is not well-formed XML is left
    to Mitsuba, whose message then is the same as without it."""
    path = os.fspath(path)
    text = read_scene_text(path)
    defines = dict(defines or {})
    strict_error = None  # why the text could not be edited, if it could not
    try:
        edited = text if edit is None else edit(text, path)
        check_affine_matrices(edited, path, defines)
        try:
            if resolution is not None:
                edited = set_film_size(edited, resolution, path)
        except SceneSyntaxError as e:
            edited, strict_error = text, e  # Mitsuba reports where the syntax error is
        if edited is text:
            scene = mi.load_file(path, parallel=PARALLEL_LOAD, **defines)
        else:
            scene = load_string_in(os.path.dirname(os.path.abspath(path)), edited,
                                   **_still_used(defines, text, edited))
    except SceneError:
        raise
    except Exception as e:  # Mitsuba reports parse/plugin errors as RuntimeError
        if "KeyboardInterrupt" in str(e):  # Ctrl-C in a Python plugin, as Mitsuba's error text
            raise KeyboardInterrupt from e
        message = _mitsuba_message(e, path)
        raise SceneError(_unused_defines_message(message, path, text)
                         or _one_line_load_error(message, path)) from None
    if not isinstance(scene, mi.Scene):
        raise SceneError(f"{path}: the file does not describe a <scene>")
    if strict_error is not None:
        # Mitsuba's parser took what strict XML refuses: never render at
        # another resolution than the one asked for without a word.
        width, height = resolution
        raise SceneError(f"{strict_error}; the resolution {width}x{height} cannot be set in it "
                         "(render without --resolution, or fix the XML)")
    from ..plugin.shape import warn_open_dielectrics  # (needs a variant: imported here)

    warn_open_dielectrics(scene)  # (open dielectric sheets no other sheet closes)
    return scene
