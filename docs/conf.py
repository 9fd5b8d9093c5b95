"""Sphinx configuration of the northfinder documentation.

Build it from the repository's root (the ``docs`` extra installs what it needs)::

    pip install -e '.[docs]'
    sphinx-build -W --keep-going -b html docs build/docs

The pages are Markdown (MyST); the API reference is generated from the numpydoc docstrings of the
installed package (autodoc and napoleon). ``protocol.md`` and ``BENCHMARKS.md`` stay at the
repository's root and are included by ``protocol.md`` and ``benchmarks.md`` here.
"""

from pathlib import Path

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
    "sphinx.ext.intersphinx",
    "sphinx_copybutton",
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

# sphinx-copybutton: a code block's button copies the commands, not the prompts or the output.
# Console blocks (Pygments marks `$ ` prompts .gp and output .go) and text blocks with `$ ` or
# `>>> ` prompts: only the prompt lines are copied, without their prompt; a block without any
# prompt is copied whole.
copybutton_exclude = ".linenos, .gp, .go"
copybutton_prompt_text = r"\$ |>>> |\.\.\. "
copybutton_prompt_is_regexp = True
copybutton_only_copy_prompt_lines = True
copybutton_remove_prompts = True

# intersphinx: links into other projects' docs need their objects.inv, and the build machines
# reach no documentation site (only the package registries). Python's inventory is read where
# an installed copy of the Python docs has one (Debian: `apt-get install python3-doc`); numpy's
# and python-can's ship in no package. Without an inventory the mapping is left out (intersphinx
# would warn, and CI builds with -W), and nitpicky mode (`sphinx-build -n`) ignores the names
# below instead of reporting each.
_PYTHON_INVENTORIES = [
    p
    for p in sorted(Path("/usr/share/doc").glob("python3*/html/objects.inv"), reverse=True)
    if p.is_file()
]
intersphinx_mapping = (
    {"python": ("https://docs.python.org/3", str(_PYTHON_INVENTORIES[0]))}
    if _PYTHON_INVENTORIES
    else {}
)

# Nitpicky mode (-n), reason by reason: names Sphinx cannot resolve and that are not mistakes.
nitpick_ignore_regex = [
    # numpy: no inventory offline (above); its types in annotations and numpydoc type lines.
    ("py:.*", r"(numpy|np)\..*"),
    ("py:.*", r"ndarray|array_like|u?int(8|16|32|64)|float(16|32|64)|bool_?|complex128"),
    # python-can: no inventory offline (above).
    ("py:.*", r"can\..*"),
    # The standard library where no Python inventory is installed, and its names as autodoc
    # writes them from an annotation's short form (Path for pathlib.Path).
    ("py:.*", r"(collections\.abc|typing|pathlib|os|io|logging|argparse|socket|enum|datetime)\..*"),
    ("py:.*", r"Path|Callable|Iterator|Iterable|Sequence|Mapping|Any|TextIO|BinaryIO|Self"),
    # numpydoc type lines are prose, which napoleon turns into references word by word:
    # "array of shape (n, 3), optional", literals such as {"virtual", "slcan-pty"}, phrases.
    ("py:class", r".*\s.*|.*[\"'{}()\[\]].*|\d+|optional|shape|n|m|k|callable|pairs|value|of|or"),
    # The API reference documents the public names (northfinder.__all__, docs/api.rst); the
    # docstrings of the modules behind them name internals (classes, functions, constants and
    # attributes of other modules) that have no page of their own.
    ("py:.*", r"northfinder\..*"),
]
