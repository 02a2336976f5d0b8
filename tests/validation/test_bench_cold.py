"""The cold first-render measurement of the benchmarks (validation/bench.py):
a fresh process with an empty kernel cache, its time split into compilation
and execution."""

from __future__ import annotations

from conftest import SCENES, VARIANT

from lathe_shape.validation.bench import cold_first_render_parts


def test_cold_first_render_parts():
    parts = cold_first_render_parts(SCENES / "wine_glass.xml", "lathe_path", VARIANT,
                                    {"res": "8", "spp": "1", "max_depth": "2", "mesh_segments": "16"})
    assert parts["operations"] and all(count > 0 for count in parts["operations"])
    # A cold cache: every kernel was compiled, within the render's time.
    assert 0 < parts["backend"] < parts["seconds"]
    assert parts["codegen"] > 0 and parts["execution"] > 0
