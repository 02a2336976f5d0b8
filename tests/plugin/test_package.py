"""Package-level behaviour: LLVM check, registration across variant changes."""

from __future__ import annotations

import re

import drjit as dr
import mitsuba as mi
import pytest

import lathe_shape


def test_llvm_check_names_the_fix(monkeypatch):
    monkeypatch.setattr(dr.detail, "llvm_version", lambda: (15, 0, 7))
    monkeypatch.delenv("LATHE_SHAPE_SKIP_LLVM_CHECK", raising=False)
    with pytest.raises(RuntimeError, match=re.escape(
            "needs libLLVM >= 19, but Dr.Jit found libLLVM 15.0.7")) as info:
        lathe_shape.check_llvm("llvm_ad_rgb")
    assert "apt-get install -y libllvm19" in str(info.value)
    # Not an LLVM variant: nothing to check.
    lathe_shape.check_llvm("cuda_ad_rgb")
    monkeypatch.setenv("LATHE_SHAPE_SKIP_LLVM_CHECK", "1")
    lathe_shape.check_llvm("llvm_ad_rgb")


@pytest.mark.skipif(not mi.variant().startswith("llvm"), reason="checks the libLLVM of LLVM variants")
def test_llvm_found_here_is_supported():
    assert tuple(dr.detail.llvm_version()) >= lathe_shape.MIN_LLVM_VERSION


def test_plugins_follow_variant_changes():
    original = mi.variant()
    xml = ("<scene version='3.0.0'><shape type='lathe'>"
           "<string name='profile' value='0 0, 1 0, 1 1, 0 1'/></shape></scene>")
    try:
        mi.set_variant("scalar_rgb")
        with pytest.raises(RuntimeError, match="Mitsuba variant 'scalar_rgb' is not supported"):
            mi.load_string(xml)
    finally:
        mi.set_variant(original)
    scene = mi.load_string(xml)
    assert type(scene.shapes()[0]).__name__ == "LatheShape"
    assert mi.load_dict({"type": "lathe_path"}).normal_check == "fallback"



_SPECTRAL_SCRIPT = """
import sys
import mitsuba as mi
mi.set_variant(sys.argv[1])
import lathe_shape
T = mi.ScalarTransform4f
def scene(integrator):
    return mi.load_dict({"type": "scene", "integrator": integrator,
        "sensor": {"type": "perspective", "fov": 35,
                   "to_world": T().look_at([0, -6, 3], [0, 0, 0.7], [0, 0, 1]),
                   "film": {"type": "hdrfilm", "width": 16, "height": 16},
                   "sampler": {"type": "independent", "sample_count": 64}},
        "sky": {"type": "constant", "radiance": {"type": "rgb", "value": 0.5}},
        "floor": {"type": "rectangle", "to_world": T().scale([6, 6, 1]), "bsdf": {"type": "diffuse"}},
        "glass": {"type": "lathe", "profile": "0 0, 1 0, 1.2 1, 0.6 2, 0 2",
                  "to_world": T().translate([0, 0, 0.01]), "bsdf": {"type": "dielectric"}}})
for name in sys.argv[2:]:
    try:
        print(name, float(mi.render(scene({"type": name, "max_depth": 8}), seed=1).numpy().mean()))
    except Exception as error:
        print(name, "error:", str(error).strip().splitlines()[-1])
"""


def _render_in(variant: str, *integrators: str) -> dict[str, str]:
    """Render a glass lathe with each integrator in a new process whose
    variant is set before lathe_shape is imported: ``{name: mean or error}``."""
    import subprocess
    import sys
    result = subprocess.run([sys.executable, "-c", _SPECTRAL_SCRIPT, variant, *integrators],
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-2000:]
    lines = [line.split(" ", 1) for line in result.stdout.splitlines()]
    return {line[0]: line[1] for line in lines if line[0] in integrators}


def test_spectral_variant_renders():
    """lathe_path renders a glass in a spectral variant as path does (the
    RGB guides are not built without aovs)."""
    backend = mi.variant().split("_")[0]
    out = _render_in(f"{backend}_ad_spectral", "lathe_path", "path")
    exact, mesh = float(out["lathe_path"]), float(out["path"])
    assert exact > 0.1 and abs(exact / mesh - 1) < 0.03


def test_polarized_variant_refused():
    """lathe_path and lathe_whitted refuse polarized variants with a clear
    message; lathe_prb carries polarization and renders."""
    backend = mi.variant().split("_")[0]
    variant = f"{backend}_ad_spectral_polarized"
    out = _render_in(variant, "lathe_path", "lathe_whitted", "lathe_prb")
    for name in ("lathe_path", "lathe_whitted"):
        assert out[name].startswith("error: "), out[name]
        assert (f"{name}: Mitsuba variant '{variant}' is not supported: this integrator does not carry "
                "polarization (Mueller matrices); use an unpolarized variant") in out[name]
    assert float(out["lathe_prb"]) > 0.1


def test_aovs_need_an_rgb_variant(monkeypatch):
    from lathe_shape.plugin import lathe_path
    monkeypatch.setattr(lathe_path.mi, "is_rgb", False, raising=False)
    with pytest.raises(ValueError, match=re.escape(
            "lathe_path: parameter 'aovs' needs an RGB variant (the guides are RGB images); this is '")):
        props = mi.Properties("lathe_path")
        props["aovs"] = "albedo"
        lathe_path.LathePathIntegrator(props)


def test_switching_jit_variants_is_refused_clearly():
    """Plugin classes derive from the import-time variant's Mitsuba classes:
    another JIT variant gets a clear error, the original one works again."""
    original = mi.variant()
    backend = original.split("_")[0]
    other = f"{backend}_ad_mono" if original != f"{backend}_ad_mono" else f"{backend}_ad_rgb"
    try:
        mi.set_variant(other)
        with pytest.raises(RuntimeError, match=re.escape(
                f"lathe_path: Mitsuba variant '{other}' is not supported: lathe_shape was imported under "
                f"the variant '{original}'")):
            mi.load_dict({"type": "lathe_path"})
    finally:
        mi.set_variant(original)
    assert mi.load_dict({"type": "lathe_path"}).normal_check == "fallback"
