"""Sphinx configuration of the surfidx documentation (``docs/``).

Build: ``sphinx-build -W -n -b html docs docs/_build/html`` (``tests/test_docs.py`` does it,
warnings as errors). Pages are Markdown (MyST) or reStructuredText; a new page is a file and a
line in a ``toctree`` (the benchmark pages are picked up by a glob).
"""

from __future__ import annotations

import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE / "_ext"))
sys.path.insert(0, str(HERE.parent))          # the repository's surfidx and ingest

import surfidx  # noqa: E402  (before numpy: the portable numerics profile)
import surfidx.cli  # noqa: E402

surfidx.cli.load_all()                        # every command registered for sphinx-click

project = "surfidx"
author = "the surfidx authors"
copyright = "the surfidx authors"
release = version = surfidx.__version__

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "numpydoc",
    "sphinx_click",
    "surfidx_api",
]
source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
exclude_patterns = ["_build", "_ext", "Thumbs.db", ".DS_Store"]
root_doc = "index"

# every reference must resolve (surfidx_api sends aliases to the documented object)
nitpicky = True
surfidx_external_roots = ("numpy", "np", "scipy", "trimesh", "click", "dask", "distributed",
                          "faiss", "PIL", "sqlite3", "os", "pathlib")

autodoc_member_order = "bysource"
autodoc_typehints = "none"                    # types are in the numpydoc sections
numpydoc_show_class_members = False           # autodoc lists the members
numpydoc_class_members_toctree = False
numpydoc_xref_param_type = False              # "(n, 3) float64" is a shape, not a class
numpydoc_validation_checks = set()

myst_enable_extensions = ["colon_fence", "deflist", "dollarmath"]
myst_heading_anchors = 3

html_theme = "furo"
html_title = f"surfidx {release}"
html_static_path = []
numpydoc_attributes_as_param_list = False   # an attribute is a target of :attr:
smartquotes = False                           # "--db" stays two hyphens in help texts
