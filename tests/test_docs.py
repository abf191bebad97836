"""The documentation site (``make docs``: Sphinx + MyST-NB, docs/): it builds offline, every page opens in headless
Chromium from disk with no console error and no request outside its own files, no internal link is broken, and
the API reference lists the package's classes (``hbeo.model.inference.HBEO``). The README and the pages say
what the project is, not how it was made: no issue numbers, sessions, step ids or retired scripts in their prose,
every script they name exists, and every figure they show is a committed file."""
import re
import shutil
import subprocess
import sys
from pathlib import Path
from urllib.parse import unquote, urlsplit

import pytest

from hbeo.report import book

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
CHROMIUM = next((p for p in (shutil.which("chromium"), "/usr/bin/chromium") if p and Path(p).is_file()), None)
#: The README and the site's own pages (``docs/history/`` holds dated logs, not pages).
PAGES = [ROOT / "README.md", *sorted(DOCS.glob("*.md"))]
#: Pages the site must have (``make docs`` -> ``docs/_build/html``), by their file in the built site.
EXPECTED = ["index.html", "install.html", "reproduce.html", "method.html", "your-depth-image.html", "scale.html",
            "architecture.html", "experiments.html", "notebooks.html", "_api/index.html", "_api/model.html",
            "_notebooks/01_voxelize.html", "_notebooks/08_your_depth_image.html"]


def _prose(text: str) -> str:
    """Text outside generated blocks, fenced code and inline code."""
    text = re.sub(r"<!-- (\S+):.*?<!-- /\1 -->", "", text, flags=re.S)
    text = re.sub(r"```.*?```", "", text, flags=re.S)
    return re.sub(r"`[^`\n]*`", "", text)


#: What the README and the pages must not say: work-log talk and names of retired tools.
#: (Case-insensitive, except a step id: lower case, so that "3D" is not one.)
WORK_LOG = {"an issue number": r"(?i)\bissues? #?\d+", "a session": r"(?i)\bsessions?\b",
            "the brief": r"(?i)\bthe brief\b", "a step id": r"\b(?:[Ss]teps? )?\d[a-z]\b(?!-)",
            "model_table.sh": r"model_table\.sh"}


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_pages_describe_the_project_not_its_work_log(page):
    text = page.read_text()
    prose = _prose(text)
    for what, pattern in WORK_LOG.items():
        found = re.findall(pattern, prose)
        assert not found, f"{page.name} names {what} in its prose: {found}"


def test_the_lint_catches_work_log_talk():
    prose = _prose("Made over two sessions (issue 29, step 4k; `--rotation 6d` is code).\n")
    assert [bool(re.search(p, prose)) for p in WORK_LOG.values()] == [True, True, False, True, False]
    assert not re.search(WORK_LOG["a step id"], _prose("3D ShapeNets, 30³ grids, 2 h, agree to ~1e-7"))


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.relative_to(ROOT).as_posix())
def test_scripts_and_figures_named_exist(page):
    """Every ``scripts/X`` or ``maintainer/X`` a page names outside generated blocks (its prose and commands) is
    there, and every image it shows is committed."""
    text = re.sub(r"<!-- (\S+):.*?<!-- /\1 -->", "", page.read_text(), flags=re.S)
    for path in set(re.findall(r"\b((?:scripts|maintainer)/[\w.-]+\.(?:py|sh))", text)):
        assert (ROOT / path).is_file(), f"{page.name} names {path}, which does not exist"
    for src in re.findall(r"!\[[^\]]*\]\(([^)\s]+)\)", text):
        target = (page.parent / src).resolve().relative_to(ROOT)
        tracked = subprocess.run(["git", "ls-files", "--error-unmatch", str(target)], cwd=ROOT, capture_output=True)
        assert tracked.returncode == 0, f"{page.name} shows {src}, which is not a committed file"


def test_docs_requirements_are_pinned_and_declared():
    """The docs' packages: exact pins in requirements.txt (what ``make setup`` installs) and the ``docs`` extra."""
    import tomllib
    pins = dict(line.split("==") for line in (ROOT / "requirements.txt").read_text().splitlines()
                if "==" in line and not line.startswith("#"))
    extra = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]["docs"]
    for name in ("sphinx", "myst-parser", "myst-nb", "furo"):
        assert name in {k.lower() for k in pins}, f"{name} is not pinned in requirements.txt"
        assert any(re.match(rf"{name}\b", e, flags=re.I) for e in extra), f"{name} is not in the docs extra"
    assert "docs:" in (ROOT / "Makefile").read_text()


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    """The site built as ``make docs`` builds it, into a temporary folder; and the build's warnings."""
    out = tmp_path_factory.mktemp("site")
    proc = subprocess.run([sys.executable, "-m", "sphinx", "-b", "html", "-q", "-d", str(out / "doctrees"),
                           str(DOCS), str(out / "html")], cwd=ROOT, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr[-4000:]
    return out / "html", proc.stderr


@pytest.mark.slow
def test_the_site_builds_with_every_page(site):
    html, warnings = site
    missing = [p for p in EXPECTED if not (html / p).is_file()]
    assert not missing, f"pages missing from the site: {missing}"
    ours = [w for w in warnings.splitlines() if re.match(rf"{re.escape(str(DOCS))}/[\w-]+\.md", w)]
    assert not ours, "warnings from the docs' own pages:\n" + "\n".join(ours)
    # the API pages too: a docstring whose reStructuredText breaks renders as a jumble (a table cut off, a
    # definition list run into one paragraph)
    docstrings = [w for w in warnings.splitlines() if "docstring of" in w]
    assert not docstrings, "warnings from docstrings:\n" + "\n".join(docstrings)
    for page in html.rglob("*.html"):
        text = page.read_text()
        assert book.remote_references(text) == [], f"{page.relative_to(html)} loads from the network"
        assert not re.search(r"<script[^>]*mathjax|MathJax\s*=", text, flags=re.I), f"{page.relative_to(html)} loads MathJax"
    method = (html / "method.html").read_text()
    assert "<math" in method and "$o'" not in method, "math is written as MathML"
    assert 'id="hbeo.model.inference.HBEO"' in (html / "_api" / "model.html").read_text()


def _anchors(path: Path, cache: dict) -> set:
    if path not in cache:
        cache[path] = set(re.findall(r'\bid="([^"]+)"', path.read_text())) if path.suffix == ".html" else set()
    return cache[path]


@pytest.mark.slow
def test_chromium_opens_every_page_offline_with_no_broken_link(site):
    """Headless Chromium opens every page of the site from disk: no console error, no request outside file://,
    every image loaded, every link inside the site to a file that exists (and an anchor that exists in it); the
    API reference lists hbeo.model.inference.HBEO."""
    if CHROMIUM is None:
        pytest.skip("no chromium binary (scripts/setup.sh installs Debian's chromium)")
    from playwright.sync_api import sync_playwright
    html, _ = site
    pages = sorted(p for p in html.rglob("*.html") if "_static" not in p.parts)
    broken, cache = [], {}
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=CHROMIUM)
        try:
            for path in pages:
                name = path.relative_to(html).as_posix()
                page = browser.new_page()
                errors, remote = [], []
                page.on("console", lambda m: errors.append(m.text) if m.type == "error" else None)
                page.on("pageerror", lambda e: errors.append(str(e)))
                page.on("requestfailed", lambda r: errors.append(f"failed: {r.url}"))
                page.on("request", lambda r: remote.append(r.url)
                        if not r.url.startswith(("file:", "data:", "blob:", "about:")) else None)
                page.goto(path.as_uri(), wait_until="load")
                sizes = page.evaluate("Array.from(document.images).map(i => i.complete ? i.naturalWidth : 0)")
                links = page.evaluate("Array.from(document.querySelectorAll('a[href]')).map(a => a.href)")
                assert errors == [], f"{name}: {errors}"
                assert remote == [], f"{name} asked the network for {remote}"
                assert all(w > 0 for w in sizes), f"{name}: images not loaded: {sizes}"
                for link in links:
                    url = urlsplit(link)
                    if url.scheme != "file":
                        continue
                    target = Path(unquote(url.path))
                    if not target.exists():
                        broken.append(f"{name} -> {link}")
                    elif url.fragment and target.is_file() and unquote(url.fragment) not in _anchors(target, cache):
                        broken.append(f"{name} -> {link} (no such anchor)")
                if name == "_api/model.html":
                    assert page.locator('[id="hbeo.model.inference.HBEO"]').count() == 1
                    assert "hbeo.model.inference.HBEO" in page.inner_text("body")
                page.close()
        finally:
            browser.close()
    assert not broken, "broken links:\n" + "\n".join(broken)
