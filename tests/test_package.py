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
