"""The run's book: a run folder's executed notebooks and products as a static HTML site that opens offline.

:func:`build_book` reads a run folder (:class:`hbeo.rundir.RunDir`, as ``python -m hbeo reproduce`` leaves it:
the executed notebooks ``NN_name.ipynb``, ``manifest.json``, the Markdown tables ``*.md`` and the figures
``*.png``) and writes, into ``out_dir`` (default ``RUN/book/``)::

    index.html        the run's title, the manifest's summary (commit, profile, dataset, wall times), one link per
                      notebook, every Markdown table rendered, every figure shown
    NN_name.html      one page per executed notebook (nbconvert's HTMLExporter, its ``lab`` template)
    figures/NN_x.png  copies of the run's figures, linked relatively (16-bit PNGs are depth data, not figures:
                      they are listed, not shown)

Nothing loads from another host, so the folder opens from disk with no network and can be copied anywhere:
the ``lab`` template's require.js, MathJax, mermaid and widget scripts are left out (executed notebooks carry
no JavaScript outputs; widget outputs fall back to their text), LaTeX math (``$...$``, ``$$...$$``) becomes
MathML at build time (``latex2mathml``; browsers draw MathML natively), notebook images are embedded as data
URIs and the template's CSS comments (they cite web pages) are dropped. :func:`remote_references` lists what
a page would still fetch from the network (``src``, ``<link href>``, CSS ``url()`` / ``@import``, ...), and
:func:`build_book` refuses to write a page that has any. Hyperlinks a notebook's text makes to web pages stay
links: they load nothing.

Command line: ``python -m hbeo.report.book RUN [OUT]`` (``make book PROFILE=cpu DATASET=procedural``).
The book is written atomically, as one folder (:func:`build_book`).

May import: foundation (nbconvert, nbformat, latex2mathml and Pillow lazily).
"""
from __future__ import annotations

import html
import re
from pathlib import Path

from hbeo.errors import DataError
from hbeo.rundir import RunDir

#: The book's folder inside a run (``RUN/book/``) and its figures' subfolder.
BOOK_DIR, FIGURES_DIR = "book", "figures"
#: Executed notebooks of a run folder (``NN_name.ipynb``, :meth:`hbeo.rundir.RunDir.notebook`).
NOTEBOOK_GLOB = "[0-9][0-9]_*.ipynb"
#: Output types dropped from notebooks: they need scripts from the network (widgets, require.js).
SCRIPT_MIMES = ("application/vnd.jupyter.widget-view+json", "application/vnd.jupyter.widget-state+json",
                "application/javascript", "text/javascript")
#: nbconvert's ``lab`` template without the blocks that load scripts from a CDN.
_TEMPLATE_NAME = "hbeo_book.html.j2"
_TEMPLATE = r"""{%- extends 'lab/index.html.j2' -%}
{%- block html_head_js_requirejs -%}{%- endblock html_head_js_requirejs -%}
{%- block jupyter_widgets -%}{%- endblock jupyter_widgets -%}
{%- block html_head_js_mathjax -%}{%- endblock html_head_js_mathjax -%}
{%- block html_head_js_mermaidjs -%}{%- endblock html_head_js_mermaidjs -%}
{%- block html_head_css -%}<style type="text/css">
nav.hbeo-book { font-family: sans-serif; font-size: 14px; padding: 8px 0; }
math[display="block"] { margin: 0.6em 0; }
</style>{%- endblock html_head_css -%}
{%- block body_header -%}{{ super() }}
<nav class="hbeo-book"><a href="index.html">&larr; {{ resources.book_title | e }}</a></nav>
{%- endblock body_header -%}
"""
_REMOTE = re.compile(
    r"""(?:\b(?:src|srcset|poster|data|action|formaction)\s*=\s*["']?\s*(?:https?:)?//"""
    r"""|<link\b[^>]*\bhref\s*=\s*["']?\s*(?:https?:)?//"""
    r"""|\burl\(\s*["']?\s*(?:https?:)?//|@import\s+(?:url\()?\s*["']?\s*(?:https?:)?//)""", re.I)
_STYLE = re.compile(r"(<style[^>]*>)(.*?)(</style>)", re.S | re.I)
_MATHML_NS = ' xmlns="http://www.w3.org/1998/Math/MathML"'
_PAGE_CSS = """body { font-family: sans-serif; max-width: 1100px; margin: 2em auto; padding: 0 1em; color: #222; }
table { border-collapse: collapse; margin: 0.5em 0 1.5em; font-size: 13px; }
th, td { border: 1px solid #ccc; padding: 3px 8px; text-align: left; }
td.num, th.num { text-align: right; }
figure { display: inline-block; margin: 0 1em 1.5em 0; vertical-align: top; }
figure img { max-width: 100%; border: 1px solid #ddd; }
figcaption { font-size: 13px; color: #555; }
code { background: #f4f4f4; padding: 0 3px; }"""


def remote_references(page: str) -> list[str]:
    """What an HTML page would load from another host: ``src=``/``srcset=``/... attributes, ``<link href>``,
    CSS ``url()`` and ``@import`` that name an ``http(s)://`` or protocol-relative address (snippets of the
    page, [] for a page that opens offline). Hyperlinks (``<a href>``) load nothing and are not listed."""
    return [page[m.start():m.start() + 120] for m in _REMOTE.finditer(page)]


def _mathml(tex: str, display: str) -> str:
    """LaTeX ``tex`` as inline or block MathML (no namespace attribute: HTML5 knows ``<math>``); the TeX
    source as code when latex2mathml cannot read it."""
    from latex2mathml.converter import convert
    try:
        return convert(tex, display=display).replace(_MATHML_NS, "")
    except Exception:                       # a construct latex2mathml lacks: show the source, never fail
        return f"<code>{html.escape(tex)}</code>"


def _renderer_class():
    """nbconvert's Markdown renderer with math written as MathML instead of left for MathJax."""
    from nbconvert.filters.markdown_mistune import IPythonRenderer

    class MathMLRenderer(IPythonRenderer):
        def inline_math(self, body: str) -> str:
            return _mathml(body, "inline")

        def block_math(self, body: str) -> str:
            return _mathml(body, "block")

        def latex_environment(self, name: str, body: str) -> str:
            return _mathml(f"\\begin{{{name}}}{body}\\end{{{name}}}", "block")

    return MathMLRenderer


def markdown_html(text: str) -> str:
    """Markdown (GitHub tables, LaTeX math) -> an HTML fragment, as the notebook pages render it."""
    from nbconvert.filters.markdown_mistune import MarkdownWithMath
    return MarkdownWithMath(renderer=_renderer_class()(escape=False)).render(text)


def _exporter():
    """An HTMLExporter on :data:`_TEMPLATE` whose Markdown math becomes MathML and images are embedded."""
    import jinja2
    from nbconvert import HTMLExporter
    from nbconvert.filters.markdown_mistune import MarkdownWithMath
    Renderer = _renderer_class()

    class BookExporter(HTMLExporter):
        @jinja2.pass_context
        def markdown2html(self, context, source):
            cell = context.get("cell", {})
            path = context.get("resources", {}).get("metadata", {}).get("path", "")
            renderer = Renderer(escape=False, attachments=cell.get("attachments", {}), embed_images=True, path=path,
                                anchor_link_text=self.anchor_link_text, exclude_anchor_links=self.exclude_anchor_links)
            return MarkdownWithMath(renderer=renderer).render(source)

    return BookExporter(template_name="lab", template_file=_TEMPLATE_NAME, embed_images=True,
                        extra_loaders=[jinja2.DictLoader({_TEMPLATE_NAME: _TEMPLATE})])


def _offline_notebook(nb, title: str):
    """``nb`` (nbformat node, changed in place) without the outputs that need scripts from the network
    (:data:`SCRIPT_MIMES`; an output left with nothing is dropped) and its widget state, with each cell's stream
    outputs merged and a text progress bar's frames reduced to its last (nbconvert's
    ``CoalesceStreamsPreprocessor``: what a terminal or JupyterLab shows of ``\\r``); titled ``title``."""
    from nbconvert.preprocessors import CoalesceStreamsPreprocessor
    nb.metadata.pop("widgets", None)
    nb.metadata["title"] = title
    for cell in nb.cells:
        outs = []
        for out in cell.get("outputs", []):
            data = out.get("data")
            if data is not None:
                for mime in SCRIPT_MIMES:
                    data.pop(mime, None)
                if not data:
                    continue
            outs.append(out)
        if "outputs" in cell:
            cell["outputs"] = outs
            CoalesceStreamsPreprocessor().preprocess_cell(cell, {}, 0)
    return nb


def notebook_page(path, book_title: str, exporter=None) -> str:
    """The HTML page (str) of one executed notebook ``path`` (``.ipynb``); DataError naming the file when
    it cannot be read or its page would load anything from the network."""
    import nbformat
    path = Path(path)
    try:
        nb = nbformat.read(path, as_version=4)
    except Exception as err:
        raise DataError(path, f"unreadable notebook ({type(err).__name__}: {err})") from None
    nb = _offline_notebook(nb, f"{path.stem} · {book_title}")
    resources = {"metadata": {"name": path.stem, "path": str(path.parent)}, "book_title": book_title}
    page, _ = (exporter or _exporter()).from_notebook_node(nb, resources=resources)
    page = _STYLE.sub(lambda m: m.group(1) + re.sub(r"/\*.*?\*/", "", m.group(2), flags=re.S) + m.group(3), page)
    remote = remote_references(page)
    if remote:
        raise DataError(path, f"its page would load {len(remote)} resources from the network, e.g. {remote[0]!r}")
    return page


def _is_figure(png: Path) -> bool:
    """A PNG meant to be looked at (8-bit), not data (16-bit or float depth images)."""
    from PIL import Image
    try:
        with Image.open(png) as im:
            return im.mode not in ("I", "I;16", "I;16B", "I;16L", "F")
    except Exception:
        return False


def notebook_wall_s(manifest: dict) -> dict[str, float]:
    """{notebook stem: wall seconds} from a run's manifest (``notebooks`` entries, or the older
    ``wall_time_s`` map)."""
    nbs = manifest.get("notebooks")
    if isinstance(nbs, dict):
        return {k: v.get("wall_s") for k, v in nbs.items() if isinstance(v, dict)}
    old = manifest.get("wall_time_s")
    return dict(old) if isinstance(old, dict) else {}


def _minutes(sec) -> str:
    return "–" if not isinstance(sec, (int, float)) else f"{sec / 60:.1f} min" if sec >= 60 else f"{sec:.0f} s"


def _summary_html(m: dict, run: RunDir) -> str:
    e = html.escape
    commit = m.get("git_commit") or "unknown"
    hw = m.get("hardware") if isinstance(m.get("hardware"), dict) else {}
    rows = [("run folder", run.name), ("profile", m.get("profile", "–")), ("dataset", m.get("dataset", "–")),
            ("commit", commit + (" (uncommitted changes)" if m.get("git_dirty") else "")
             + (f", tag {m['git_tag']}" if m.get("git_tag") else "")),
            ("all notebooks at one commit", {True: "yes", False: "no"}.get(m.get("one_commit"), "–")),
            ("wall time (notebooks)", _minutes(m.get("wall_time_total_s"))),
            ("hardware", ", ".join(f"{k} {v}" for k, v in hw.items() if k in ("cpu", "cores", "gpu", "memory_gib")
                                   and v is not None) or "–"),
            ("updated", m.get("updated", "–")), ("command", m.get("command", "–"))]
    if not m:
        rows = [("run folder", run.name), ("manifest", "none (run the notebooks with python -m hbeo reproduce)")]
    return "<table>" + "".join(f"<tr><th>{e(k)}</th><td>{e(str(v))}</td></tr>" for k, v in rows) + "</table>"


def _index_html(title: str, run: RunDir, manifest: dict, pages: list[tuple[str, str]], tables: list[Path],
                figures: list[str], data_pngs: list[str]) -> str:
    e = html.escape
    wall = notebook_wall_s(manifest)
    parts = [f"<!DOCTYPE html>\n<html lang=\"en\">\n<head>\n<meta charset=\"utf-8\" />\n<title>{e(title)}</title>\n"
             f"<style>\n{_PAGE_CSS}\n</style>\n</head>\n<body>\n<h1>{e(title)}</h1>",
             "<h2>The run</h2>", _summary_html(manifest, run), "<h2>Notebooks</h2>",
             "<table><tr><th>notebook</th><th class=\"num\">wall time</th></tr>"]
    parts += [f"<tr><td><a href=\"{e(href)}\">{e(stem)}</a></td><td class=\"num\">{_minutes(wall.get(stem))}</td></tr>"
              for stem, href in pages]
    parts.append("</table>")
    if tables:
        parts.append("<h2>Tables</h2>")
        for t in tables:
            parts += [f"<h3 id=\"{e(t.stem)}\">{e(t.name)}</h3>", markdown_html(t.read_text())]
    if figures:
        parts.append("<h2>Figures</h2>")
        parts += [f"<figure><img src=\"{e(FIGURES_DIR)}/{e(f)}\" alt=\"{e(f)}\" /><figcaption>{e(f)}</figcaption>"
                  "</figure>" for f in figures]
    if data_pngs:
        parts.append("<h2>Data images</h2><p>16-bit PNGs in the run folder (depth images in millimetres, not "
                     "pictures): " + ", ".join(f"<code>{e(p)}</code>" for p in data_pngs) + ".</p>")
    parts.append("</body>\n</html>\n")
    return "\n".join(parts)


def _is_book(folder: Path) -> bool:
    """Whether ``folder`` holds nothing but what :func:`build_book` writes (``index.html``, ``NN_name.html``,
    ``figures/*.png``, temporaries ``.*.tmp``): a folder it may replace. Not a run folder, nor one with a user's
    files."""
    def ours(p: Path, names) -> bool:
        return p.name.startswith(".") and p.name.endswith(".tmp") or any(p.match(n) for n in names)
    for p in folder.iterdir():
        if p.is_dir() and not p.is_symlink() and p.name == FIGURES_DIR:
            if not all(q.is_file() and ours(q, ["*.png"]) for q in p.iterdir()):
                return False
        elif not (p.is_file() and ours(p, ["index.html", "[0-9][0-9]_*.html"])):
            return False
    return True


def _replace_folder(new: Path, out: Path) -> None:
    """Put the finished folder ``new`` where ``out`` is (a sibling): renamed into place, an earlier ``out`` moved
    aside first and removed once ``new`` stands there (moved back if that rename fails)."""
    import shutil
    if not out.exists():
        new.rename(out)
        return
    old = out.with_name(f"{new.name}.old")
    out.rename(old)
    try:
        new.rename(out)
    except BaseException:
        old.rename(out)
        raise
    shutil.rmtree(old, ignore_errors=True)


def build_book(run, out_dir=None) -> Path:
    """Write the book of run folder ``run`` (RunDir or path) into ``out_dir`` (default ``RUN/book/``; see the
    module docstring for what it holds) and return its ``index.html``. DataError when ``run`` has no executed
    notebook, a notebook cannot be read, its manifest is damaged (:meth:`~hbeo.rundir.RunDir.read_manifest`), a
    page would load anything from the network, or ``out_dir`` holds anything but an earlier book.

    The whole book is built in a hidden sibling folder (``.book.XXXX.tmp``) and renamed into place only when every
    page is written, replacing the earlier book: a failure leaves that book as it was and no partial one (never
    pages of two runs under one index). Pages of notebooks no longer in the run and figures no longer there are
    gone with the earlier book."""
    import os
    import shutil
    import tempfile
    from hbeo.storage import current_umask
    run = RunDir.of(run)
    notebooks = sorted(run.path.glob(NOTEBOOK_GLOB))
    if not notebooks:
        raise DataError(run.path, "no executed notebooks (NN_name.ipynb) in this run folder; "
                                  "run `python -m hbeo reproduce` first")
    out = Path(out_dir) if out_dir is not None else run.path / BOOK_DIR
    target = Path(os.path.abspath(out))
    if target.exists() and (not target.is_dir() or target.is_symlink() or not _is_book(target)):
        raise DataError(target, "holds files that are not a book of hbeo's (a book replaces the folder it is "
                                "written to): name a new or empty folder, or an earlier book")
    manifest = run.read_manifest()
    target.parent.mkdir(parents=True, exist_ok=True)
    stage = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent))
    try:
        os.chmod(stage, 0o777 & ~current_umask())          # as a plain mkdir makes it (mkdtemp: 0700)
        _write_book(run, notebooks, manifest, stage)
        _replace_folder(stage, target)
    except DataError as err:
        shutil.rmtree(stage, ignore_errors=True)
        left = f"the book in {out} is left as it was" if target.exists() else "no book written"
        raise DataError(err.path, f"{err.problem} ({left})") from None
    except BaseException:
        shutil.rmtree(stage, ignore_errors=True)
        raise
    return out / "index.html"


def _write_book(run: RunDir, notebooks: list[Path], manifest: dict, out: Path) -> None:
    """Every page, figure and the index of the book into the (new, empty) folder ``out``."""
    import shutil
    title = f"hbeo run {run.name}"
    exporter = _exporter()
    pages = []
    for nb in notebooks:
        href = f"{nb.stem}.html"
        (out / href).write_text(notebook_page(nb, title, exporter), encoding="utf-8")
        pages.append((nb.stem, href))
    pngs = sorted(run.path.glob("*.png"))
    figures = [p for p in pngs if _is_figure(p)]
    for p in figures:
        (out / FIGURES_DIR).mkdir(exist_ok=True)
        shutil.copyfile(p, out / FIGURES_DIR / p.name)
    tables = sorted(run.path.glob("*.md"))
    index = _index_html(title, run, manifest, pages, tables, [p.name for p in figures],
                        [p.name for p in pngs if p not in figures])
    remote = remote_references(index)
    if remote:
        raise DataError(run.path, f"the book's index would load resources from the network, e.g. {remote[0]!r}")
    (out / "index.html").write_text(index, encoding="utf-8")
