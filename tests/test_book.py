"""The run's book (`make book`, hbeo.report.book): pages for every executed notebook, the index with the
manifest, tables and figures, nothing loaded from the network, and a real browser shows it without errors."""
import base64
import io
import json
import re
import shutil
from pathlib import Path

import nbformat
import numpy as np
import pytest
from PIL import Image

from hbeo import cli
from hbeo.errors import DataError
from hbeo.report import book

CHROMIUM = next((p for p in (shutil.which("chromium"), "/usr/bin/chromium") if p and Path(p).is_file()), None)


def _png(width=40, height=30, mode="RGB", value=200) -> bytes:
    arr = np.full((height, width, 3) if mode == "RGB" else (height, width), value,
                  np.uint8 if mode == "RGB" else np.uint16)
    buf = io.BytesIO()
    Image.fromarray(arr).save(buf, format="PNG")
    return buf.getvalue()


def _executed_notebook(path: Path) -> None:
    """A small notebook as papermill leaves it: Markdown with math, a text output, a PNG figure, an HTML
    table, a progress-bar widget (its state in the metadata) with a text fallback."""
    nb = nbformat.v4.new_notebook()
    nb.metadata["widgets"] = {"application/vnd.jupyter.widget-state+json": {"state": {}, "version_major": 2}}
    nb.cells = [
        nbformat.v4.new_markdown_cell("# 01 · A tiny notebook\n\nAn object is $o' = W^\\top o$; "
                                      "$$\\lVert D - \\hat D \\rVert_2$$"),
        nbformat.v4.new_code_cell("print('hello')", execution_count=1,
                                  outputs=[nbformat.v4.new_output("stream", name="stdout", text="hello\n")]),
        nbformat.v4.new_code_cell("fig", execution_count=2, outputs=[nbformat.v4.new_output(
            "display_data", data={"image/png": base64.b64encode(_png()).decode(), "text/plain": "<Figure>"})]),
        nbformat.v4.new_code_cell("table", execution_count=3, outputs=[nbformat.v4.new_output(
            "execute_result", execution_count=3,
            data={"text/html": "<table><tr><th>class</th><td>bathtub</td></tr></table>", "text/plain": "table"})]),
        nbformat.v4.new_code_cell("progress", execution_count=4, outputs=[nbformat.v4.new_output(
            "display_data", data={"application/vnd.jupyter.widget-view+json": {"model_id": "abc", "version_major": 2,
                                                                              "version_minor": 0},
                                  "text/plain": "progress 100%"})]),
    ]
    nbformat.write(nb, path)


@pytest.fixture()
def run_folder(tmp_path):
    """A run folder as ``python -m hbeo reproduce`` leaves it, in miniature."""
    run = tmp_path / "ci-procedural"
    run.mkdir()
    _executed_notebook(run / "01_tiny.ipynb")
    _executed_notebook(run / "02_other.ipynb")
    (run / "05_table1.md").write_text("| method | accuracy |\n| --- | ---: |\n| HBEO | 81.8 |\n")
    (run / "05_confusion.png").write_bytes(_png(64, 48))
    (run / "08_depth_mm.png").write_bytes(_png(16, 12, mode="I;16", value=1500))      # data, not a figure
    manifest = {"profile": "ci", "dataset": "procedural", "git_commit": "0123456789abcdef", "git_dirty": False,
                "notebooks": {"01_tiny": {"wall_s": 12.5, "commit": "0123456789abcdef", "dirty": False},
                              "02_other": {"wall_s": 75.0, "commit": "0123456789abcdef", "dirty": False}},
                "wall_time_total_s": 87.5, "one_commit": True}
    (run / "manifest.json").write_text(json.dumps(manifest))
    return run


def test_build_book_writes_every_page_offline(run_folder):
    index = book.build_book(run_folder)
    out = run_folder / book.BOOK_DIR
    assert index == out / "index.html"
    pages = sorted(p.name for p in out.glob("*.html"))
    assert pages == ["01_tiny.html", "02_other.html", "index.html"]
    text = index.read_text()
    for expected in ("0123456789abcdef", "ci", "procedural", "1.5 min", 'href="01_tiny.html"', 'href="02_other.html"',
                     "<td>HBEO</td>", 'src="figures/05_confusion.png"', "08_depth_mm.png"):
        assert expected in text, expected
    assert (out / "figures" / "05_confusion.png").read_bytes() == (run_folder / "05_confusion.png").read_bytes()
    assert not (out / "figures" / "08_depth_mm.png").exists(), "a 16-bit depth image is data, not a figure"
    page = (out / "01_tiny.html").read_text()
    assert "<math" in page and "$o'" not in page, "math is written as MathML"
    assert re.search(r'<img[^>]+src="data:image/png;base64,', page), "notebook images are embedded"
    assert "progress 100%" in page and "widget-view" not in page and "widget-state" not in page
    assert 'href="index.html"' in page
    for p in out.rglob("*.html"):
        body = p.read_text()
        assert "http://" not in body and "https://" not in body, f"{p.name} names an address on the network"
        assert book.remote_references(body) == []


def test_rebuild_drops_pages_of_notebooks_gone(run_folder):
    book.build_book(run_folder)
    (run_folder / "02_other.ipynb").unlink()
    (run_folder / "05_confusion.png").unlink()
    book.build_book(run_folder)
    out = run_folder / book.BOOK_DIR
    assert not (out / "02_other.html").exists() and not (out / "figures" / "05_confusion.png").exists()


def _files(folder: Path) -> dict:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def test_a_failed_rebuild_leaves_the_earlier_book_as_it_was(run_folder, capsys):
    """One notebook unreadable: no page of the new run joins the earlier book's index, and no partial book is left
    (the book is built beside it and renamed into place only when whole)."""
    book.build_book(run_folder)
    out = run_folder / book.BOOK_DIR
    before = _files(out)
    nb = nbformat.read(run_folder / "01_tiny.ipynb", as_version=4)
    nb.cells[0].source = "# 01 · the notebook of another run"
    nbformat.write(nb, run_folder / "01_tiny.ipynb")                 # its page is built before 02's fails
    (run_folder / "02_other.ipynb").write_text('{"cells": [{"cell_type": "mark')
    (run_folder / "06_new.png").write_bytes(_png(20, 10))
    assert cli.main(["book", str(run_folder)]) == 2
    assert _files(out) == before
    assert sorted(p.name for p in run_folder.iterdir() if p.name.startswith(".")) == []      # no partial book
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"error: {run_folder / '02_other.ipynb'}: unreadable notebook") and "left as it was" in err


def test_a_failed_first_build_leaves_no_book(run_folder, tmp_path):
    (run_folder / "02_other.ipynb").write_text("not a notebook")
    with pytest.raises(DataError) as err:
        book.build_book(run_folder, tmp_path / "site")
    assert not (run_folder / book.BOOK_DIR).exists() and sorted(p.name for p in tmp_path.iterdir()) == ["ci-procedural"]
    assert "02_other.ipynb: unreadable notebook" in str(err.value) and "no book written" in str(err.value)


def test_a_folder_that_is_not_a_book_is_never_replaced(run_folder, tmp_path):
    """The book replaces the folder it is written to: one holding anything else (the run folder itself, a user's
    notes) is refused and left as it was."""
    (tmp_path / "site").mkdir()
    (tmp_path / "site" / "notes.txt").write_text("mine")
    for out in (tmp_path / "site", run_folder):
        before = _files(out)
        with pytest.raises(DataError, match="not a book of hbeo's"):
            book.build_book(run_folder, out)
        assert _files(out) == before
    book.build_book(run_folder, tmp_path / "empty")                  # a new folder, and an earlier book, are fine
    assert (tmp_path / "empty" / "index.html").is_file()
    book.build_book(run_folder, tmp_path / "empty")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ci-procedural", "empty", "site"]


def test_a_damaged_manifest_is_named(run_folder):
    (run_folder / "manifest.json").write_text('{"profile": "ci", "hardware": "laptop"}')
    with pytest.raises(DataError, match=r"manifest.json: key 'hardware' holds text \('laptop'\)"):
        book.build_book(run_folder)
    assert not (run_folder / book.BOOK_DIR).exists()


def test_remote_references_finds_what_would_load():
    page = ('<script src="https://cdn.example/x.js"></script><link rel="stylesheet" href="//cdn.example/a.css">'
            '<style>@import url("http://x/y.css"); .a { background: url(https://x/bg.png) }</style>'
            '<img srcset="https://x/1.png 1x">')
    assert len(book.remote_references(page)) == 5
    assert book.remote_references('<a href="https://example.org/paper">paper</a><img src="figures/a.png">') == []


def test_bad_run_folders_are_refused(tmp_path, capsys):
    with pytest.raises(DataError, match="no executed notebooks"):
        book.build_book(tmp_path)
    assert cli.main(["book", str(tmp_path)]) == 2
    assert "no executed notebooks" in capsys.readouterr().err


def test_command_line_writes_to_the_folder_given(run_folder, tmp_path, capsys):
    assert cli.main(["book", str(run_folder), str(tmp_path / "site")]) == 0
    assert (tmp_path / "site" / "index.html").is_file() and "site" in capsys.readouterr().out


def test_chromium_shows_the_book_without_errors(run_folder):
    """Headless Chromium opens the index and a notebook page from disk: no console error, no request to the
    network, every image loaded."""
    if CHROMIUM is None:
        pytest.skip("no chromium binary (scripts/setup.sh installs Debian's chromium)")
    from playwright.sync_api import sync_playwright
    out = run_folder / book.BOOK_DIR
    book.build_book(run_folder)
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM)
        try:
            for name in ("index.html", "01_tiny.html"):
                page = browser.new_page()
                errors, remote = [], []
                page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
                page.on("pageerror", lambda e: errors.append(str(e)))
                page.on("requestfailed", lambda r: errors.append(f"failed: {r.url}"))
                page.on("request", lambda r: remote.append(r.url) if not r.url.startswith(("file:", "data:")) else None)
                page.goto((out / name).as_uri(), wait_until="load")
                sizes = page.evaluate("Array.from(document.images).map(i => i.complete ? i.naturalWidth : 0)")
                assert errors == [], f"{name}: {errors}"
                assert remote == [], f"{name} asked the network for {remote}"
                assert sizes and all(w > 0 for w in sizes), f"{name}: images not loaded: {sizes}"
                if name != "index.html":
                    assert page.locator("math").count() >= 2, "MathML math is in the page"
                page.close()
        finally:
            browser.close()


@pytest.mark.slow
def test_chromium_shows_a_3d_view_offline(tmp_path):
    """A notebook page with a rotatable 3-D view (hbeo.lessons.viewer: plotly.js embedded) passes the book's
    offline check, and headless Chromium draws the plot from disk: no console error, no request to the network,
    the plotly graph rendered with a non-zero size and its 3-D scene's WebGL canvas."""
    if CHROMIUM is None:
        pytest.skip("no chromium binary (scripts/setup.sh installs Debian's chromium)")
    from playwright.sync_api import sync_playwright
    from hbeo.lessons import viewer
    grid = np.zeros((30, 30, 30), bool)
    grid[6:22, 8:22, 3:11] = True
    grid[6:22, 19:22, 11:26] = True
    pts = np.random.default_rng(0).uniform(6, 22, (300, 3))
    html = viewer.to_html(viewer.figure(viewer.View3D(grid, pts, "true pose", truth=grid, title="3-D view")))
    run = tmp_path / "ci-procedural"
    run.mkdir()
    nb = nbformat.v4.new_notebook()
    nb.cells = [nbformat.v4.new_markdown_cell("# 06 · A 3-D view"),
                nbformat.v4.new_code_cell("viewer.show(view)", execution_count=1, outputs=[nbformat.v4.new_output(
                    "display_data", data={"text/html": html, "text/plain": "<IPython.core.display.HTML object>"})])]
    nbformat.write(nb, run / "06_view.ipynb")
    book.build_book(run)
    page_file = run / book.BOOK_DIR / "06_view.html"
    assert book.remote_references(page_file.read_text()) == []
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM)
        try:
            page = browser.new_page()
            errors, remote = [], []
            page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
            page.on("pageerror", lambda e: errors.append(str(e)))
            page.on("requestfailed", lambda r: errors.append(f"failed: {r.url}"))
            page.on("request", lambda r: remote.append(r.url) if not r.url.startswith(("file:", "data:", "blob:"))
                    else None)
            page.goto(page_file.as_uri(), wait_until="load")
            page.wait_for_selector(".js-plotly-plot", state="attached", timeout=20_000)
            size = page.evaluate("(() => { const r = document.querySelector('.js-plotly-plot').getBoundingClientRect();"
                                 " return [r.width, r.height]; })()")
            drawn = page.evaluate("(() => { const d = document.querySelector('.js-plotly-plot');"
                                  " return [d.data.length, !!(d._fullLayout.scene && d._fullLayout.scene._scene),"
                                  " d.querySelectorAll('canvas').length]; })()")
            assert errors == [], errors
            assert remote == [], f"the page asked the network for {remote}"
            assert size[0] > 100 and size[1] > 100, size
            assert drawn[0] == 4 and drawn[1] and drawn[2] >= 1, drawn
        finally:
            browser.close()


def test_a_text_bar_shows_its_last_frame_in_the_book(tmp_path):
    """A notebook papermill ran directly holds its bars as stderr text with one frame per carriage return."""
    nb = nbformat.v4.new_notebook()
    nb.cells = [nbformat.v4.new_code_cell("train()", execution_count=1, outputs=[
        nbformat.v4.new_output("stream", name="stderr", text="train:  10%|#    | 1/10 FIRSTFRAME\r"),
        nbformat.v4.new_output("stream", name="stderr", text="train: 100%|#####| 10/10 LASTFRAME\n"),
        nbformat.v4.new_output("stream", name="stdout", text="done\n")])]
    nbformat.write(nb, tmp_path / "04_train.ipynb")
    page = book.notebook_page(tmp_path / "04_train.ipynb", "ci-procedural")
    assert "LASTFRAME" in page and "FIRSTFRAME" not in page and "done" in page

