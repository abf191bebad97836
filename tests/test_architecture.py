"""The package's shape: imports go one way along the paper's pipeline, modules stay small, nothing
unpickles, notebooks only call the package."""
import ast
import json
import re
from pathlib import Path

import pytest

PKG = Path(__file__).resolve().parent.parent / "hbeo"
NOTEBOOKS = PKG.parent / "notebooks"
#: The pipeline order, bottom to top; a module may import its own layer and those below it. A layer is a
#: subpackage folder (its modules are whatever the folder holds) or one top-level module named here
#: (``run``, ``cli``); every other top-level module is the foundation. Nothing lists files by hand.
LAYERS = ["foundation", "data", "subspace", "render", "model", "baselines", "run", "evaluation", "report",
          "lessons", "cli"]
TOP_LEVEL = {"run": "run", "cli": "cli", "__main__": "cli"}
MAX_LINES = 520


def _subpackages() -> list[str]:
    return sorted(p.parent.name for p in PKG.glob("*/__init__.py"))


def _layer(module: str) -> str:
    """Layer of a dotted module name inside hbeo (``hbeo.render.poses`` -> ``render``)."""
    parts = module.split(".")
    assert parts[0] == "hbeo", module
    if len(parts) == 1:
        return "foundation"
    head = parts[1]
    if (PKG / head).is_dir():
        assert head in LAYERS, f"hbeo/{head}/ belongs to no layer: place it in LAYERS"
        return head
    return TOP_LEVEL.get(head, "foundation")


def _modules():
    for path in sorted(PKG.rglob("*.py")):
        rel = path.relative_to(PKG.parent).with_suffix("")
        name = ".".join(rel.parts)
        yield path, name[: -len(".__init__")] if name.endswith(".__init__") else name


def _imports(path: Path, name: str):
    """Every hbeo module ``path`` imports, at any depth (function-level imports included)."""
    tree = ast.parse(path.read_text())
    package = name if path.name == "__init__.py" else name.rsplit(".", 1)[0]
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for a in node.names:
                if a.name.split(".")[0] == "hbeo":
                    yield node.lineno, a.name
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                mod = ".".join(base + ([node.module] if node.module else []))
            else:
                mod = node.module or ""
            if mod.split(".")[0] != "hbeo":
                continue
            for a in node.names:   # `from hbeo import data` imports the subpackage hbeo.data
                sub = f"{mod}.{a.name}"
                yield node.lineno, sub if (PKG.parent / sub.replace(".", "/")).exists() or \
                    (PKG.parent / (sub.replace(".", "/") + ".py")).exists() else mod


def test_the_layers_cover_every_module():
    for _, name in _modules():
        _layer(name)
    assert set(_subpackages()) <= set(LAYERS), "a subpackage without a place in LAYERS"


def test_evaluation_never_imports_a_presentation_layer():
    """The statistics compute, the report presents: the code version that keys cached evaluations leaves
    out exactly the layers above the evaluation, so none of them may be imported below it."""
    from hbeo.evaluation.protocol import PRESENTATION_LAYERS
    assert set(PRESENTATION_LAYERS) == set(LAYERS[LAYERS.index("evaluation") + 1:-1])


def test_imports_go_one_way_along_the_pipeline():
    bad = []
    for path, name in _modules():
        mine = LAYERS.index(_layer(name))
        for line, target in _imports(path, name):
            theirs = LAYERS.index(_layer(target))
            if theirs > mine:
                bad.append(f"{path.relative_to(PKG.parent)}:{line} ({_layer(name)}) imports {target} ({_layer(target)})")
    assert not bad, "imports against the pipeline direction:\n" + "\n".join(bad)


def test_the_direction_check_can_fail(tmp_path):
    """The checker itself sees a function-level import of a later layer."""
    p = tmp_path / "x.py"
    p.write_text("def f():\n    from hbeo.report import tables\n")
    found = list(_imports(p, "hbeo.data.x"))
    assert found == [(2, "hbeo.report.tables")]
    assert LAYERS.index(_layer(found[0][1])) > LAYERS.index(_layer("hbeo.data.x"))


def test_every_module_has_a_docstring_and_stays_small():
    problems = []
    for path, name in _modules():
        if path.name == "__main__.py":
            continue
        tree = ast.parse(path.read_text())
        doc = ast.get_docstring(tree)
        if not doc:
            problems.append(f"{name}: no module docstring")
        n = len(path.read_text().splitlines())
        if n > MAX_LINES and "one file because" not in (doc or ""):
            problems.append(f"{name}: {n} lines and no stated reason ('one file because ...') in its docstring")
    assert not problems, "\n".join(problems)


def test_subpackages_say_what_they_may_import():
    for sub in _subpackages():
        doc = ast.get_docstring(ast.parse((PKG / sub / "__init__.py").read_text())) or ""
        assert "May import" in doc, f"hbeo/{sub}/__init__.py must say what it may import"


def test_nothing_unpickles():
    pattern = re.compile(r"weights_only\s*=\s*False|allow_pickle\s*=\s*True|\bpickle\.loads?\(|\bdill\b|joblib\.load")
    hits = [f"{p.relative_to(PKG.parent)}:{i}" for p, _ in _modules()
            for i, line in enumerate(p.read_text().splitlines(), 1) if pattern.search(line)]
    assert not hits, "unpickling code: " + ", ".join(hits)


@pytest.mark.parametrize("nb", sorted(NOTEBOOKS.glob("*.ipynb")), ids=lambda p: p.stem)
def test_notebooks_only_call_the_package(nb):
    cells = json.loads(nb.read_text())["cells"]
    code = [("".join(c["source"]), c) for c in cells if c["cell_type"] == "code"]
    assert all(not c.get("outputs") and c.get("execution_count") is None for _, c in code), \
        f"{nb.name}: committed notebooks carry no outputs"
    for src, _ in code:
        tree = ast.parse("\n".join(line for line in src.splitlines() if not line.lstrip().startswith(("%", "!"))))
        defs = [n.name for n in ast.walk(tree) if isinstance(n, (ast.FunctionDef, ast.ClassDef, ast.Lambda))
                and hasattr(n, "name")]
        assert not defs, f"{nb.name} defines {defs}: logic belongs in the package"


def test_per_profile_numbers_live_only_in_config():
    """No module outside config.py keys a table by profile name or branches on one."""
    pattern = re.compile(r"""["'](ci|cpu|full)["']\s*:\s*[\d(\[{]|==\s*["'](ci|cpu|full)["']""")
    hits = [f"{p.relative_to(PKG.parent)}:{i}: {line.strip()}" for p, name in _modules() if name != "hbeo.config"
            for i, line in enumerate(p.read_text().splitlines(), 1) if pattern.search(line)]
    assert not hits, "per-profile numbers outside hbeo/config.py:\n" + "\n".join(hits)


def _named_modules(package: str, doc: str) -> set[str]:
    """Modules of ``hbeo.<package>`` the docstring refers to as ``:mod:`~hbeo.<package>.<module>``` (or
    without the ``~``)."""
    return set(re.findall(rf":mod:`~?hbeo\.{package}\.(\w+)`", doc))


@pytest.mark.parametrize("package", _subpackages())
def test_package_docstrings_list_every_module(package):
    """Each subpackage's docstring names every module the folder holds (a :mod: reference), and only those:
    the docstring is the package's table of contents, so it must not fall behind the folder."""
    init = PKG / package / "__init__.py"
    doc = ast.get_docstring(ast.parse(init.read_text())) or ""
    modules = {p.stem for p in (PKG / package).glob("*.py") if p.stem != "__init__"}
    named = _named_modules(package, doc)
    assert not modules - named, f"hbeo/{package}/__init__.py does not name {sorted(modules - named)}"
    assert not named - modules, f"hbeo/{package}/__init__.py names modules that do not exist: {sorted(named - modules)}"


def test_the_docstring_check_sees_a_missing_module():
    assert _named_modules("data", "the grids (:mod:`~hbeo.data.voxel`, :mod:`hbeo.data.gridset`)") == {"voxel",
                                                                                                     "gridset"}
    assert _named_modules("data", "procedural objects (hbeo.data.procedural)") == set()


def _architecture_rows() -> list[list[str]]:
    text = (PKG.parent / "docs" / "architecture.md").read_text()
    section = text[text.index("## Layers"):text.index("\n## ", text.index("## Layers") + 1)]
    return [[c.strip() for c in line.strip("|").split("|")] for line in section.splitlines()
            if line.startswith("| ") and not line.startswith("| layer") and not line.startswith("| ---")]


def test_readme_architecture_table_is_the_code_s():
    """The docs' layer table (docs/architecture.md) names every layer in order, and every type and function it
    names exists."""
    rows = _architecture_rows()
    firsts = [r[0] for r in rows]
    named = [next((layer for layer in LAYERS if f"`hbeo/{layer}/`" in c or f"`hbeo/{layer}.py`" in c
                   or c.startswith(layer)), None) for c in firsts]
    assert named == LAYERS, f"docs/architecture.md's layer table lists {named}, the layers are {LAYERS}"
    source = "\n".join(p.read_text() for p in PKG.rglob("*.py"))
    for row in rows:
        for name in re.findall(r"`([\w.]+)", row[2]):
            leaf = name.split(".")[-1]
            assert re.search(rf"^\s*(def|class) {leaf}\b|^{leaf}\s*=", source, re.M), \
                f"docs/architecture.md's layer table names {name}, which the package does not define"
