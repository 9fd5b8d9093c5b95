"""Sphinx configuration of the northfinder documentation.

Build it from the repository's root (the ``docs`` extra installs what it needs)::

    pip install -e '.[docs]'
    sphinx-build -n -W --keep-going -b html docs build/docs

The pages are Markdown (MyST); the API reference is generated from the numpydoc docstrings of the
installed package (autodoc and napoleon). ``protocol.md`` and ``BENCHMARKS.md`` stay at the
repository's root and are included by ``protocol.md`` and ``benchmarks.md`` here.
"""

import functools
import re
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
# would warn, and CI builds with -W), and nitpicky mode (`sphinx-build -n`, as CI builds) ignores the names
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


# Short names in docstrings (:meth:`close`, :data:`SOLVERS`, :class:`Clock`) are resolved where
# the docstring is: in its class, then its module. A name exported by the package links to its
# entry (northfinder.HostError); a name that exists there but has no entry of its own (an
# internal constant, an inherited method) is shown as code, like the internals above. A name
# found nowhere is a mistake and stays a warning.
_MISSING = object()


@functools.cache
def _source(klass):
    import inspect

    try:
        return inspect.getsource(klass)
    except (OSError, TypeError):
        return ""


def _attribute(owner, name):
    import inspect

    value = getattr(owner, name, _MISSING)
    if value is not _MISSING or not inspect.isclass(owner):
        return value
    for klass in owner.__mro__:  # a dataclass field without a default, an instance attribute
        if name in getattr(klass, "__annotations__", {}):
            return name
        if f"self.{name} =" in _source(klass) or f"self.{name}:" in _source(klass):
            return name
    return _MISSING


def _resolve(dotted):
    """The object of a dotted path (a module, then attributes), or _MISSING."""
    import importlib

    parts = dotted.split(".")
    for i in range(len(parts), 0, -1):
        try:
            value = importlib.import_module(".".join(parts[:i]))
        except ImportError:
            continue
        for part in parts[i:]:
            value = _attribute(value, part)
            if value is _MISSING:
                break
        return value
    return _MISSING


def _scopes(node):
    """Where a short name in this reference may live: the documented object and its class, the
    context's class, their modules, the context's module."""
    import inspect
    import sys

    scopes = []
    source = node.source or ""
    if "docstring of " in source:
        dotted = source.rpartition("docstring of ")[2].strip()
        while dotted:
            value = _resolve(dotted)
            if value is not _MISSING:
                scopes.append(value)
            dotted = dotted.rpartition(".")[0]
    module, cls = node.get("py:module"), node.get("py:class")
    if module and cls:
        scopes.append(_resolve(f"{module}.{cls}"))
    if module:
        scopes.append(_resolve(module))
    for value in list(scopes):
        home = inspect.getmodule(value)
        if home is not None:
            scopes.append(home)
    # An annotation of a function has its module's context only: the package's modules.
    scopes += [m for n, m in sorted(sys.modules.items()) if n.startswith("northfinder.")]
    return [s for s in scopes if s is not _MISSING and s is not None]


def _lookup(target, node):
    for scope in _scopes(node):
        value = scope
        for part in target.split("."):
            value = _attribute(value, part)
            if value is _MISSING:
                break
        else:
            return value
    return _resolve(target) if "." in target else _resolve(f"northfinder.{target}")


def _short_name(app, env, node, contnode):
    if node.get("refdomain") != "py":
        return None
    target = node["reftarget"].lstrip(".~")
    value = _lookup(target, node)
    if value is _MISSING:
        return None
    name = getattr(value, "__name__", None)
    if (
        isinstance(name, str)
        and name in northfinder.__all__
        and getattr(northfinder, name) is value
    ):
        domain = env.get_domain("py")
        ref = domain.resolve_xref(
            env, node["refdoc"], app.builder, node["reftype"], f"northfinder.{name}", node, contnode
        )
        if ref is not None:
            return ref
    return contnode


# viewcode's "[docs]" links on the source pages lead back to an object's entry: viewcode writes one
# page and one prefix per module (the last page that showed the module, the first name it was
# shown under), which the module pages (api/*.rst, shown with :no-index:, no anchors) make wrong.
# Once the site is written each one is pointed at the entry the Python domain has for the name
# (northfinder.Device in api.html), and dropped where the name has no entry (an internal).
_BACKLINK = re.compile(r'<a class="viewcode-back" href="[^"]*#([^"]+)">([^<]*)</a>\n?')


def _viewcode_backlinks(app, exception):
    if exception is not None or app.builder.format != "html":
        return
    objects = app.env.get_domain("py").objects
    modules = getattr(app.env, "_viewcode_modules", {})
    out = Path(app.outdir)
    for page in sorted((out / "_modules").rglob("*.html")):
        pagename = page.relative_to(out).with_suffix("").as_posix()
        modname = pagename.removeprefix("_modules/").replace("/", ".")
        entry = modules.get(modname)
        tags = entry[1] if entry else {}

        def point(match, pagename=pagename, modname=modname, tags=tags):
            anchor = match.group(1)
            names = [t for t in tags if anchor == t or anchor.endswith(f".{t}")]
            name = max(names, key=len, default=anchor)
            for full in (anchor, f"{modname}.{name}", f"northfinder.{name}"):
                obj = objects.get(full)
                if obj is not None and not obj.aliased:
                    uri = app.builder.get_relative_uri(pagename, obj.docname)
                    return f'<a class="viewcode-back" href="{uri}#{obj.node_id}">{match.group(2)}</a>\n'
            return ""

        text = page.read_text(encoding="utf-8")
        fixed = _BACKLINK.sub(point, text)
        if fixed != text:
            page.write_text(fixed, encoding="utf-8")


def setup(app):
    app.connect("missing-reference", _short_name)
    app.connect("build-finished", _viewcode_backlinks)
