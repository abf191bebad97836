"""Sphinx configuration of hbeo's documentation (``make docs`` -> ``docs/_build/html/index.html``).

Sphinx with MyST-NB: the pages are MyST Markdown (``docs/*.md``), the notebooks are rendered from
``notebooks/`` without running them, and the API reference is autodoc over the package's own docstrings
(reStructuredText roles such as :func:, which Sphinx resolves). Why this tool: docs/install.md, *The
documentation*. The build is offline (no intersphinx) and the site loads nothing from the network: math is
MathML written at build time (``_ext/hbeo_mathml.py``), the theme's assets are local files.

Two sets of pages are written here at each build, into folders git ignores: ``_notebooks/`` (copies of
``notebooks/*.ipynb``: Sphinx reads only inside its source folder) and ``_api/`` (one page per layer of the
package, listing every module, so a new module appears without editing anything).
"""
from __future__ import annotations

import re
import shutil
import sys
from pathlib import Path

DOCS = Path(__file__).resolve().parent
ROOT = DOCS.parent
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(DOCS / "_ext"))

project = "hbeo"
author = "the hbeo authors"
copyright = "hbeo authors, MIT licence"
release = version = "0.1.0"

extensions = ["myst_nb", "sphinx.ext.autodoc", "sphinx.ext.napoleon", "hbeo_mathml"]
html_math_renderer = "mathml"

myst_enable_extensions = ["dollarmath", "colon_fence", "deflist"]
myst_heading_anchors = 3
nb_execution_mode = "off"             # committed notebooks carry no outputs; the run's book shows executed ones
nb_ipywidgets_js = {}                 # no widget manager from a CDN
nb_merge_streams = True

exclude_patterns = ["_build", "history", "README.md", "Thumbs.db", ".DS_Store"]
suppress_warnings = ["myst.header"]

autodoc_default_options = {"members": True, "show-inheritance": True}
autodoc_member_order = "bysource"
autodoc_typehints = "description"
autodoc_mock_imports = ["pyrender", "OpenGL"]       # optional backend; its modules document themselves without it
napoleon_google_docstring = False
napoleon_numpy_docstring = True

html_theme = "furo"
html_title = "hbeo: Hybrid Bayesian Eigenobjects, reproduced"
html_static_path: list[str] = []
html_show_sourcelink = False
html_copy_source = False
html_last_updated_fmt = None


# ---- pages written at build time ----------------------------------------------------------------------------

def _write(path: Path, text: str) -> None:
    """Write ``text`` to ``path`` only when it changes (Sphinx rebuilds what is newer)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    if not path.exists() or path.read_text() != text:
        path.write_text(text)


def _copy_notebooks() -> None:
    out = DOCS / "_notebooks"
    wanted = {p.name for p in (ROOT / "notebooks").glob("[0-9][0-9]_*.ipynb")}
    for stale in out.glob("*.ipynb"):
        if stale.name not in wanted:
            stale.unlink()
    for name in sorted(wanted):
        src, dst = ROOT / "notebooks" / name, out / name
        if not dst.exists() or dst.read_bytes() != src.read_bytes():
            out.mkdir(exist_ok=True)
            shutil.copyfile(src, dst)


#: The API reference's pages: (page, title, modules or packages). Every module of the package is on one page
#: (the foundation's top-level modules on the first), in the layers' order, bottom to top.
LAYERS = [("foundation", "Foundation", None), ("data", "hbeo.data", "data"), ("subspace", "hbeo.subspace", "subspace"),
          ("render", "hbeo.render", "render"), ("model", "hbeo.model", "model"),
          ("baselines", "hbeo.baselines", "baselines"), ("run", "hbeo.run", None),
          ("evaluation", "hbeo.evaluation", "evaluation"), ("report", "hbeo.report", "report"),
          ("lessons", "hbeo.lessons", "lessons"), ("cli", "hbeo.cli", None)]
TOP_LEVEL_OWN_PAGE = {"run", "cli"}


def _automodule(name: str) -> str:
    return f"## `{name}`\n\n```{{eval-rst}}\n.. automodule:: {name}\n   :members:\n```\n"


def _write_api() -> None:
    pkg = ROOT / "hbeo"
    top = sorted(p.stem for p in pkg.glob("*.py") if p.stem not in {"__init__", "__main__"} | TOP_LEVEL_OWN_PAGE)
    pages = []
    for page, title, sub in LAYERS:
        if sub:
            mods = sorted(p.stem for p in (pkg / sub).glob("*.py") if p.stem != "__init__")
            intro = f"```{{eval-rst}}\n.. automodule:: hbeo.{sub}\n```\n"
            body = "\n".join(_automodule(f"hbeo.{sub}.{m}") for m in mods)
        elif page == "foundation":
            intro = ("The bottom layer: profiles and paths, frames and the camera, errors, files, rotations, "
                     "the run folder's layout and resource checks; every other module imports from it.\n\n"
                     f"```{{eval-rst}}\n.. automodule:: hbeo\n```\n")
            body = "\n".join(_automodule(f"hbeo.{m}") for m in top)
        else:
            intro, body = "", _automodule(f"hbeo.{page}").split("\n", 2)[2]
        _write(DOCS / "_api" / f"{page}.md", f"# {title}\n\n{intro}\n{body}")
        pages.append(page)
    toc = "\n".join(pages)
    _write(DOCS / "_api" / "index.md",
           "# API reference\n\nGenerated from the package's docstrings at each build, one page per layer, bottom "
           "to top (the layers: [Architecture](../architecture.md)).\n\n"
           f"```{{toctree}}\n:maxdepth: 2\n\n{toc}\n```\n")


_copy_notebooks()
_write_api()


def _skip_foreign(app, what, name, obj, skip, options):
    """Leave out members a class inherits from another library (scikit-learn's ``set_output``,
    ``set_*_request``): their docstrings are that library's, with references this site cannot resolve."""
    module = getattr(obj, "__module__", None) or ""
    if what == "class" and module and not module.startswith("hbeo"):
        return True
    return None


#: Inline literals and interpreted text of a docstring (a literal may run over lines), left as they are by
#: :func:`_plain_text`.
_LITERAL = re.compile(r"(``[^`]+?``|`[^`]+`_{0,2})")
#: What may come right before an inline literal's start and right after its end (docutils' inline markup rules).
_BEFORE, _AFTER = set(" \t\n-:/'\"<([{"), set(" \t\n-.,:;!?\\/'\")]}>")


def _plain(text: str) -> str:
    """One stretch of a docstring outside literals, line by line, as :func:`_plain_text` says."""
    out = []
    for line in text.split("\n"):
        cells = line.strip()
        if not (cells.startswith(("+-", "+=")) or (cells.startswith("|") and cells.endswith("|") and len(cells) > 1)):
            line = re.sub(r"(?<=[A-Za-z0-9])_(?=[\s,.;:)\]]|$)", r"\\_", line.replace("|", "\\|"))
            if line.count("*") % 2 and "**" not in line:
                line = re.sub(r"\*(?=\w)", r"\\*", line)          # not a bullet's "* "
        out.append(line)
    return "\n".join(out)


def _plain_text(app, what, name, obj, options, lines):
    """Read the docstrings' plain-text notation as text, not as reST markup: ``|x|`` (a norm, an absolute value)
    is not a substitution, ``n_iter_`` (a fitted attribute) not a hyperlink reference and a lone ``*`` (``*shape``)
    not the start of emphasis, outside literals and outside the lines of a grid table (``+-`` at the start, or
    ``|`` at both ends); a literal run into a word (````what``(a)``) gets the escaped space reST needs there."""
    parts = _LITERAL.split("\n".join(lines))
    for j in range(0, len(parts), 2):                           # the even parts are outside literals
        text = _plain(parts[j])
        if j > 0 and text and text[0] not in _AFTER:
            text = "\\ " + text
        if j + 1 < len(parts) and text and text[-1] not in _BEFORE:
            text += "\\ "
        parts[j] = text
    lines[:] = "".join(parts).split("\n")


def setup(app):
    app.connect("autodoc-skip-member", _skip_foreign)
    app.connect("autodoc-process-docstring", _plain_text)
