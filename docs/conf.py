"""Sphinx configuration of the lathe_shape documentation.

Build: ``sphinx-build -W --keep-going -b html docs docs/_build/html``
(tests/test_docs.py does this with warnings as errors). Markdown pages are
read by MyST; the plugin reference is generated from the plugins'
docstrings by the local extension ``docs/_ext/lathe_plugins.py``, which
imports Mitsuba with the variant in ``LATHE_TEST_VARIANT`` (default
``llvm_ad_rgb``).
"""

import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE / "_ext"))
sys.path.insert(0, str(HERE.parent))

project = "lathe_shape"
author = "the lathe_shape authors"
copyright = "the lathe_shape authors"
release = "0.1.0"

extensions = ["myst_parser", "lathe_plugins"]
source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
root_doc = "index"
exclude_patterns = ["_build", "Thumbs.db", ".DS_Store"]
templates_path = []
html_static_path = []

myst_heading_anchors = 3
html_theme = "alabaster"
html_title = "lathe_shape"
pygments_style = "sphinx"
