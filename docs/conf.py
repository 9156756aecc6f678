"""Sphinx configuration of the gridstrain documentation.

Builds offline (no intersphinx, no remote assets): ``python3 -m sphinx -W -b html docs
docs/_build/html``. The gallery runs the scripts of ``examples/``.
"""

from __future__ import annotations

import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# the sources of this checkout, whatever gridstrain is installed
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(ROOT / "docs"))  # gallery_scraper
os.environ.setdefault("MPLBACKEND", "Agg")

import gridstrain  # noqa: E402

project = "gridstrain"
author = "gridstrain developers"
copyright = "gridstrain developers, BSD-3-Clause"
version = release = gridstrain.__version__

extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.autosummary",
    "sphinx.ext.mathjax",
    # MathJax served from the built site, not from a CDN: the site reads offline
    "sphinx-mathjax-offline",
    "numpydoc",
    "sphinx_gallery.gen_gallery",
]

exclude_patterns = ["_build", "reproduction", "architecture.md", "**/GALLERY_HEADER.rst"]
templates_path: list[str] = []
source_suffix = {".rst": "restructuredtext"}
root_doc = "index"
default_role = "code"

# --- API reference ---------------------------------------------------------------
autosummary_generate = False
autodoc_default_options = {"members": True, "member-order": "bysource"}
autodoc_typehints = "none"
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False
numpydoc_xref_param_type = False
numpydoc_validation_checks: set[str] = set()

# --- gallery ---------------------------------------------------------------------
# Scripts whose name matches run during the build; the Dask example starts worker
# processes and is shown without running it.
sphinx_gallery_conf = {
    "examples_dirs": str(ROOT / "examples"),
    "gallery_dirs": "auto_examples",
    "filename_pattern": r"/0[0-46-9]_[^/]*\.py$",
    "abort_on_example_error": True,
    "only_warn_on_example_error": False,
    "download_all_examples": False,
    "remove_config_comments": True,
    "show_memory": False,
    "plot_gallery": "True",
    "within_subsection_order": "FileNameSortKey",
    "reference_url": {"gridstrain": None},
    "matplotlib_animations": False,
    # the Figure objects gridstrain's plotting returns, then pyplot's figures
    "image_scrapers": ("gallery_scraper.library_figures", "matplotlib"),
    "capture_repr": ("_repr_html_", "__repr__"),
    "min_reported_time": 1,
}

# --- HTML --------------------------------------------------------------------------
html_theme = "pydata_sphinx_theme"
html_title = f"gridstrain {release}"
html_static_path = ["_static"]
html_show_sourcelink = False
html_theme_options = {
    "navigation_with_keys": False,
    "show_toc_level": 2,
    "header_links_before_dropdown": 6,
    "icon_links": [],
    # no call home, no analytics, nothing fetched by the reader's browser
    "check_switcher": False,
}
html_context = {"default_mode": "light"}
