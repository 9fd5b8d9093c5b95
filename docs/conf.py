"""Sphinx configuration of the northfinder documentation.

Build it from the repository's root (the ``docs`` extra installs what it needs)::

    pip install -e '.[docs]'
    sphinx-build -W --keep-going -b html docs build/docs

The pages are Markdown (MyST); the API reference is generated from the numpydoc docstrings of the
installed package (autodoc and napoleon). ``protocol.md`` and ``BENCHMARKS.md`` stay at the
repository's root and are included by ``protocol.md`` and ``benchmarks.md`` here.
"""

import northfinder

project = "northfinder"
author = "the northfinder authors"
copyright = "the northfinder authors"
version = release = northfinder.__version__

extensions = [
    "myst_parser",
    "sphinx.ext.autodoc",
    "sphinx.ext.napoleon",
    "sphinx.ext.viewcode",
]

source_suffix = {".rst": "restructuredtext", ".md": "markdown"}
root_doc = "index"
exclude_patterns = ["_build", "Thumbs.db", ".DS_Store"]

# MyST: anchors for headings up to level 4, so that pages can link to sections as `page.md#name`;
# `$` math is not enabled (the pages write units such as deg/sqrt(h) in plain text).
myst_heading_anchors = 4
myst_enable_extensions = ["colon_fence", "deflist"]

# autodoc: members in the order of the source, the signature's annotations in the description.
autodoc_member_order = "bysource"
autodoc_typehints = "description"
autodoc_default_options = {"members": True, "show-inheritance": True}
napoleon_google_docstring = False
napoleon_numpy_docstring = True
napoleon_use_rtype = False

html_theme = "furo"
html_title = f"northfinder {release}"
