"""The documentation: the README stays short, every relative link and image
of the Markdown files exists, the Sphinx site under docs/ builds with
warnings as errors (broken toctree entries, references and anchors, and
plugin docstrings that are not valid reStructuredText all fail it), and
the Python examples marked as tested run.

An example is tested when the line just before its fence is an HTML comment
starting with ``<!-- doctest`` (invisible on GitHub and in the built site).
It runs in a fresh Python process from the repository root, with the test
variant (``LATHE_TEST_VARIANT``) put in place of ``"llvm_ad_rgb"``.
"""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from conftest import ROOT, VARIANT

README = ROOT / "README.md"
DOCS = ROOT / "docs"
MARKDOWN = [README, *sorted(DOCS.glob("*.md"))]

#: The README's budget of lines (issue 25): the rest lives under docs/.
README_MAX_LINES = 200

_TESTED = re.compile(r"^<!-- doctest[^\n]*-->\n```python\n(.*?)^```", re.S | re.M)


def _tested_examples(path: Path) -> list[str]:
    """The Python blocks of ``path`` marked as tested."""
    return _TESTED.findall(path.read_text(encoding="utf-8"))


EXAMPLES = [(path, i, code) for path in MARKDOWN for i, code in enumerate(_tested_examples(path))]


def test_readme_is_short():
    lines = README.read_text(encoding="utf-8").splitlines()
    assert len(lines) <= README_MAX_LINES, f"README.md has {len(lines)} lines; move text to docs/"


def test_readme_keeps_the_commands_first():
    """The README opens with the two commands; ``.ci/run`` runs the second."""
    text = README.read_text(encoding="utf-8")
    blocks = re.findall(r"```bash\n(.*?)\n```", text, re.S)
    assert blocks[0].startswith("apt-get update") and "lathe-render scenes/brandy_bottle.xml" in blocks[0]
    assert blocks[1] == ("apt-get update && apt-get install -y libllvm19 povray povray-examples && "
                         "python3 -m venv .venv && .venv/bin/pip install -e '.[test]' && "
                         ".venv/bin/python -m pytest -q -n 2")
    assert text.index(blocks[1]) < text.index("## ")


def _link_targets(path: Path) -> list[str]:
    """The targets of the links and images of a Markdown file, as a
    CommonMark parser (markdown-it, MyST's) reads it: never in code."""
    from markdown_it import MarkdownIt

    targets = []
    for block in MarkdownIt("commonmark").enable("table").parse(path.read_text(encoding="utf-8")):
        for token in block.children or []:
            if token.type == "link_open":
                targets.append(token.attrGet("href"))
            elif token.type == "image":
                targets.append(token.attrGet("src"))
    return targets


@pytest.mark.parametrize("path", MARKDOWN, ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_exist(path):
    """Every relative link or image path of a Markdown file names a file of
    the repository (Sphinx checks the anchors; GitHub shows README.md)."""
    missing = []
    for target in _link_targets(path):
        if re.match(r"[a-z][a-z0-9+.-]*:", target) or target.startswith("#"):
            continue  # an address (https:, mailto:) or an anchor on the same page
        file = (path.parent / target.split("#", 1)[0]).resolve()
        if not file.exists():
            missing.append(target)
        elif ROOT not in file.parents:
            missing.append(f"{target} (outside the repository)")
    assert not missing, f"{path.name}: links to missing files: {missing}"


def test_readme_links_are_checked():
    """The link check sees the README's image and its links to the pages."""
    targets = _link_targets(README)
    assert "docs/wine_glass_filled.png" in targets and "docs/method.md" in targets


def test_examples_are_marked():
    """The README's example and at least three of the pages' run below."""
    assert any(path == README for path, _, _ in EXAMPLES)
    assert sum(path != README for path, _, _ in EXAMPLES) >= 3


@pytest.mark.parametrize("path,index,code", EXAMPLES,
                         ids=[f"{p.relative_to(ROOT)}-{i}" for p, i, _ in EXAMPLES])
def test_example_runs(path, index, code):
    code = code.replace('"llvm_ad_rgb"', repr(VARIANT))
    result = subprocess.run([sys.executable, "-c", code], cwd=ROOT, capture_output=True, text=True,
                            timeout=300)
    assert result.returncode == 0, (f"{path.name}, tested example {index} failed:\n{code}\n"
                                    f"{result.stdout}\n{result.stderr}")


def test_sphinx_build(tmp_path):
    """``sphinx-build -W --keep-going -b html docs OUT``: every warning (a
    broken link, reference or toctree entry, a plugin docstring that does
    not parse) fails the build."""
    try:
        import myst_parser  # noqa: F401
        import sphinx  # noqa: F401
    except ImportError as error:
        pytest.fail(f"the docs need Sphinx and MyST ({error}): pip install -e '.[test]'")
    env = dict(os.environ, LATHE_TEST_VARIANT=VARIANT)
    result = subprocess.run(
        [sys.executable, "-m", "sphinx", "-W", "--keep-going", "-q", "-b", "html",
         "-d", str(tmp_path / "doctrees"), str(DOCS), str(tmp_path / "html")],
        cwd=ROOT, env=env, capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, f"sphinx-build failed:\n{result.stdout}\n{result.stderr}"
    html = tmp_path / "html"
    for page in ("index", "plugins", "method", "architecture", "profiles", "benchmarks"):
        assert (html / f"{page}.html").is_file(), page
    reference = (html / "plugins.html").read_text(encoding="utf-8")
    for plugin in ("lathe", "lathe_path", "lathe_volpath", "lathe_whitted", "lathe_prb",
                   "dispersive_dielectric"):
        assert f"<code class=\"docutils literal notranslate\"><span class=\"pre\">{plugin}</span></code>" \
            in reference, plugin
    assert reference.count("<table") >= 6, "a parameter table per plugin"
