"""Sphinx extension: the plugin reference, generated from the plugins' docstrings.

Two directives:

``.. lathe-plugins::``
    One section per plugin that ``lathe_shape`` registers with Mitsuba (the
    ``lathe`` shape, the integrators, the BSDFs), in registration order,
    each rendering its class docstring. While a class docstring carries no
    parameter table yet, the module docstring (where the table used to be)
    is rendered after it. The plugins are found by watching
    ``lathe_shape.register()`` call Mitsuba's ``register_*`` functions, so
    a plugin added or moved later appears without editing this file.

``.. pluginparameters::``
    A parameter table in Mitsuba's own docstring format: a two-level bullet
    list, one item per parameter holding name, type and description (and
    optionally a fourth item, e.g. ``|exposed|``, appended to the
    description). Rendered as a table with the header
    ``Parameter / Type / Description``.

The type substitutions Mitsuba's documentation uses (``|int|``, ``|float|``,
``|spectrum|`` ...) are defined as plain text in every document that uses a
directive of this extension, and ``:monosp:`` is a literal.

Mitsuba is imported with the variant in ``LATHE_TEST_VARIANT`` (default
``llvm_ad_rgb``), as the tests do.
"""

from __future__ import annotations

import importlib
import inspect
import os
import re

from docutils import nodes
from docutils.parsers.rst import Directive, directives
from docutils.statemachine import StringList
from sphinx.util.nodes import nested_parse_with_titles

#: Substitutions of Mitsuba's docstrings, as plain text.
SUBSTITUTIONS = {
    "int": "int",
    "float": "float",
    "bool": "boolean",
    "boolean": "boolean",
    "string": "string",
    "spectrum": "spectrum",
    "texture": "texture",
    "bsdf": "BSDF",
    "transform": "transform",
    "medium": "medium",
    "emitter": "emitter",
    "volume": "volume",
    "tensor": "tensor",
    "point": "point",
    "vector": "vector",
    "exposed": "exposed",
    "differentiable": "differentiable",
    "discontinuous": "discontinuous",
}

#: Where each plugin's class lives, used only if watching the registration
#: finds nothing (e.g. a Mitsuba build without the ``register_*`` functions).
FALLBACK = [
    ("shape", "lathe", "lathe_shape.plugin.shape:LatheShape"),
    ("integrator", "lathe_path", "lathe_shape.plugin.lathe_path:LathePathIntegrator"),
    ("integrator", "lathe_volpath", "lathe_shape.plugin.lathe_volpath:LatheVolpathIntegrator"),
    ("integrator", "lathe_whitted", "lathe_shape.plugin.lathe_whitted:LatheWhittedIntegrator"),
    ("integrator", "lathe_prb", "lathe_shape.plugin.lathe_prb:LathePRBIntegrator"),
    ("bsdf", "dispersive_dielectric", "lathe_shape.plugin.dispersive_dielectric:DispersiveDielectric"),
]

_TABLE = re.compile(r"^\s*\.\. (pluginparameters|list-table)::", re.M)

_plugins: list[tuple[str, str, type]] | None = None


def registered_plugins() -> list[tuple[str, str, type]]:
    """(kind, name, class) of every plugin ``lathe_shape`` registers."""
    global _plugins
    if _plugins is not None:
        return _plugins
    import mitsuba as mi

    variant = os.environ.get("LATHE_TEST_VARIANT", "llvm_ad_rgb")
    if mi.variant() is None:
        mi.set_variant(variant)
    import lathe_shape

    found: list[tuple[str, str, type]] = []
    originals = {}
    for kind in ("shape", "integrator", "bsdf", "emitter", "medium", "sensor", "texture", "phase"):
        attr = f"register_{kind}"
        if hasattr(mi, attr):
            originals[attr] = getattr(mi, attr)

            def watch(name, factory, _kind=kind, _orig=originals[attr]):
                if inspect.isclass(factory):
                    found.append((_kind, name, factory))
                return _orig(name, factory)

            setattr(mi, attr, watch)
    try:
        lathe_shape.register()
    finally:
        for attr, orig in originals.items():
            setattr(mi, attr, orig)
    if not found:
        for kind, name, where in FALLBACK:
            module, cls = where.split(":")
            found.append((kind, name, getattr(importlib.import_module(module), cls)))
    # Shapes first, then integrators, then BSDFs and the rest, each kind in
    # registration order.
    kinds = ["shape", "integrator", "bsdf"]
    found.sort(key=lambda entry: kinds.index(entry[0]) if entry[0] in kinds else len(kinds))
    _plugins = found
    return found


def define_substitutions(state) -> None:
    """Define the type substitutions in the current document (once)."""
    document = state.document
    lines = [f".. |{name}| replace:: {text}" for name, text in SUBSTITUTIONS.items()
             if name not in document.substitution_defs]
    if lines:
        holder = nodes.container()
        state.nested_parse(StringList(lines, source="lathe_plugins substitutions"), 0, holder)


def monosp_role(name, rawtext, text, lineno, inliner, options=None, content=None):
    """Mitsuba's ``:monosp:`` role: a literal."""
    return [nodes.literal(rawtext, text)], []


class PluginParameters(Directive):
    """``.. pluginparameters::``: Mitsuba's parameter table."""

    has_content = True
    optional_arguments = 0
    option_spec = {"extra-rows": directives.nonnegative_int}

    def run(self):
        define_substitutions(self.state)
        holder = nodes.container()
        self.state.nested_parse(self.content, self.content_offset, holder)
        rows = []
        lists = [n for n in holder.children if isinstance(n, nodes.bullet_list)]
        if len(lists) != 1 or len(holder.children) != 1:
            error = self.state_machine.reporter.error(
                "pluginparameters: the body must be one bullet list of parameters "
                "(* - name / - type / - description)", line=self.lineno)
            return [error]
        for item in lists[0].children:
            cells = [n for n in item.children if isinstance(n, nodes.bullet_list)]
            if len(item.children) != 1 or len(cells) != 1 or len(cells[0].children) not in (3, 4):
                error = self.state_machine.reporter.error(
                    "pluginparameters: each parameter is a list of 3 items (name, type, "
                    "description) and an optional fourth", line=self.lineno)
                return [error]
            rows.append([list(cell.children) for cell in cells[0].children])

        table = nodes.table(classes=["pluginparameters"])
        group = nodes.tgroup(cols=3)
        table += group
        for width in (20, 15, 65):
            group += nodes.colspec(colwidth=width)

        def row(cells):
            entry_row = nodes.row()
            for cell in cells:
                entry = nodes.entry()
                entry.extend(cell)
                entry_row += entry
            return entry_row

        head = nodes.thead()
        head += row([[nodes.paragraph(text=t)] for t in ("Parameter", "Type", "Description")])
        group += head
        body = nodes.tbody()
        for cells in rows:
            name, kind, description = cells[:3]
            # Mitsuba writes names bare; show them as literals like the rest of the docs.
            if len(name) == 1 and isinstance(name[0], nodes.paragraph) and all(
                    isinstance(c, nodes.Text) for c in name[0].children):
                literal = nodes.paragraph()
                literal += nodes.literal(text=name[0].astext())
                name = [literal]
            if len(cells) == 4:
                description = description + cells[3]
            body += row([name, kind, description])
        group += body
        return [table]


class LathePlugins(Directive):
    """``.. lathe-plugins::``: one section per registered plugin."""

    has_content = False

    def run(self):
        define_substitutions(self.state)
        lines: list[str] = []
        for kind, name, cls in registered_plugins():
            module = inspect.getmodule(cls)
            title = f"``{name}`` ({kind})"
            lines += [title, "-" * len(title), "",
                      f"``<{kind} type=\"{name}\">``, class "
                      f"``{cls.__module__}.{cls.__qualname__}``.", ""]
            # The class's own docstring (inspect.getdoc would inherit Mitsuba's).
            doc = inspect.cleandoc(cls.__dict__.get("__doc__") or "")
            if doc:
                lines += doc.splitlines() + [""]
            if not _TABLE.search(doc) and module is not None and module.__doc__:
                lines += [f"From the module docstring of ``{module.__name__}``:", ""]
                lines += inspect.cleandoc(module.__doc__).splitlines() + [""]
        source = "lathe_plugins (docstrings)"
        content = StringList(lines, source=source)
        holder = nodes.section()
        holder.document = self.state.document
        nested_parse_with_titles(self.state, content, holder)
        return holder.children


def setup(app):
    app.add_directive("pluginparameters", PluginParameters)
    app.add_directive("lathe-plugins", LathePlugins)
    app.add_role("monosp", monosp_role)
    return {"version": "1", "parallel_read_safe": True, "parallel_write_safe": True}
