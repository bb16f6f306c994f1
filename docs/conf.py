"""Sphinx configuration of the user guide (``bash scripts/docs.sh``; warnings are errors)."""
import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
# the gallery's examples render and measure at small scale; keep their work out of the user's store
os.environ.setdefault("WORKBENCH_STORE", str(ROOT / "docs" / "_build" / "store"))
os.environ.setdefault("MPLBACKEND", "Agg")

project = "Scheimpflug stereo-DIC workbench"
author = "the workbench's authors"
copyright = "2026, " + author
extensions = ["sphinx.ext.autodoc", "sphinx.ext.napoleon", "sphinx.ext.mathjax", "sphinx_gallery.gen_gallery"]
napoleon_numpy_docstring = True
napoleon_google_docstring = False
autodoc_member_order = "bysource"
autodoc_typehints = "none"               # the numpy-style docstrings state shapes and units
sphinx_gallery_conf = {
    "examples_dirs": "examples",
    "gallery_dirs": "auto_examples",
    "filename_pattern": r"/plot_",       # every plot_*.py is run by the build
    "abort_on_example_error": True,
    "download_all_examples": False,
    "remove_config_comments": True,
    "within_subsection_order": "FileNameSortKey",
}
exclude_patterns = ["_build"]
html_theme = "alabaster"
html_theme_options = {"description": "rendered truth, the paper's instrument, scoring", "page_width": "1100px"}
nitpicky = False
