"""pyproject.toml declares what hbeo imports, and agrees with the lock (requirements.txt).

- Every third-party module imported at module level anywhere in ``hbeo/`` is provided by a core dependency
  (``pip install .`` alone must be able to import every module).
- Every one imported lazily (inside a function) is provided by a core dependency or an extra, and so is every
  one the tests import; pyrender, which cannot be declared (its PyOpenGL pin cannot load OSMesa), is in
  ``requirements-nodeps.txt`` and its own dependencies form the ``pyrender`` extra.
- Every declared lower bound admits the version requirements.txt pins, and every package it pins is declared.
"""
import ast
import re
import sys
from pathlib import Path

import pytest
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

tomllib = pytest.importorskip("tomllib")                 # Python >= 3.11
ROOT = Path(__file__).resolve().parent.parent

# import name -> distribution name, where they differ
DISTRIBUTION = {"sklearn": "scikit-learn", "skimage": "scikit-image", "PIL": "pillow", "OpenGL": "PyOpenGL",
                "IPython": "ipython", "yaml": "pyyaml"}
UNDECLARED = {"pyrender": "requirements-nodeps.txt"}      # installed --no-deps, from this file


def _pyproject() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]


def _names(reqs) -> set:
    return {canonicalize_name(Requirement(r).name) for r in reqs}


def _core() -> set:
    return _names(_pyproject()["dependencies"])


def _extras() -> dict:
    return {extra: _names(reqs) for extra, reqs in _pyproject()["optional-dependencies"].items()}


def _distribution(module: str) -> str:
    return canonicalize_name(DISTRIBUTION.get(module, module))


def third_party_imports(folder: Path, local=("hbeo",)) -> tuple[dict, dict]:
    """({module: files}, {module: files}): the top-level names of the third-party modules the .py files under
    ``folder`` import at module level (also inside a module-level try/if) and those imported only inside a
    function or class body."""
    top, lazy = {}, {}

    def visit(node, nested: bool, where: str):
        for child in ast.iter_child_nodes(node):
            names = []
            if isinstance(child, ast.Import):
                names = [a.name for a in child.names]
            elif isinstance(child, ast.ImportFrom) and not child.level:
                names = [child.module]
            for name in names:
                root = name.split(".")[0]
                if root not in sys.stdlib_module_names and root not in local:
                    (lazy if nested else top).setdefault(root, set()).add(where)
            inner = nested or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef, ast.Lambda))
            visit(child, inner, where)

    for path in sorted(folder.rglob("*.py")):
        visit(ast.parse(path.read_text(), str(path)), False, str(path.relative_to(ROOT)))
    for name in set(top) & set(lazy):          # imported at module level somewhere: a core need
        top[name] |= lazy.pop(name)
    return top, lazy


def _pins() -> dict:
    """{distribution: pinned version} of requirements.txt and requirements-nodeps.txt."""
    pins = {}
    for f in ("requirements.txt", "requirements-nodeps.txt"):
        for line in (ROOT / f).read_text().splitlines():
            line = line.split("#")[0].strip()
            if line:
                m = re.fullmatch(r"([A-Za-z0-9_.-]+)(\[[^\]]*\])?==(\S+)", line)
                assert m, f"{f}: not an exact pin: {line!r}"
                pins[canonicalize_name(m.group(1))] = m.group(3)
    return pins


def test_the_scan_sees_module_level_and_lazy_imports(tmp_path, monkeypatch):
    monkeypatch.setattr(sys.modules[__name__], "ROOT", tmp_path)
    (tmp_path / "m.py").write_text("import os\nimport numpy as np\ntry:\n    import yaml\nexcept ImportError:\n"
                                   "    pass\nfrom hbeo import config\nfrom . import sibling\n\n"
                                   "def f():\n    from skimage import measure\n    import torch.nn\n\n"
                                   "class C:\n    import plotly\n")
    (tmp_path / "n.py").write_text("def g():\n    import numpy\n")
    top, lazy = third_party_imports(tmp_path)
    assert top == {"numpy": {"m.py", "n.py"}, "yaml": {"m.py"}}
    assert lazy == {"skimage": {"m.py"}, "torch": {"m.py"}, "plotly": {"m.py"}}


def test_module_level_imports_are_core_dependencies():
    top, _ = third_party_imports(ROOT / "hbeo")
    assert "numpy" in top and "torch" in top                 # the scan sees the package
    missing = {m: sorted(f)[:3] for m, f in top.items() if _distribution(m) not in _core()}
    assert not missing, f"imported at module level but not in [project] dependencies: {missing}"


@pytest.mark.parametrize("folder", ["hbeo", "tests"])
def test_lazy_imports_are_declared(folder):
    top, lazy = third_party_imports(ROOT / folder, local={"hbeo"} | {p.stem for p in (ROOT / folder).glob("*.py")})
    if folder == "tests":
        lazy = {**lazy, **top}
    assert lazy
    declared = _core().union(*_extras().values())
    missing = {m: sorted(f)[:3] for m, f in lazy.items() if _distribution(m) not in declared and m not in UNDECLARED}
    assert not missing, f"imported but neither a dependency nor in an extra of pyproject.toml: {missing}"


def test_undeclared_pyrender_is_in_the_nodeps_file_and_its_needs_are_an_extra():
    pins = _pins()
    for module, file in UNDECLARED.items():
        assert canonicalize_name(module) in _names(
            line.split("#")[0].strip() for line in (ROOT / file).read_text().splitlines() if line.split("#")[0].strip())
        assert _distribution(module) not in _core().union(*_extras().values())
    # what pyrender 0.1.45 needs (its metadata, PyOpenGL at the version that loads OSMesa), less the core's
    assert _extras()["pyrender"] == {"pyopengl", "pyglet", "freetype-py", "imageio", "networkx", "six"}
    assert all(name in pins for name in _extras()["pyrender"])


def test_declared_bounds_admit_the_lock_and_the_lock_is_declared():
    pins = _pins()
    project = _pyproject()
    reqs = [Requirement(r) for r in project["dependencies"]]
    reqs += [Requirement(r) for extra in project["optional-dependencies"].values() for r in extra]
    reqs = [r for r in reqs if canonicalize_name(r.name) != "hbeo"]
    for r in reqs:
        assert r.specifier, f"{r}: no lower bound"
        assert not any(s.operator in ("==", "===") for s in r.specifier), f"{r}: an exact pin (pins go in the lock)"
        pin = pins.get(canonicalize_name(r.name))
        if pin is not None:
            assert r.specifier.contains(pin), f"pyproject.toml's {r} excludes requirements.txt's {r.name}=={pin}"
    assert Requirement(next(r for r in project["dependencies"] if r.startswith("numpy"))).specifier.contains("2.0")
    undeclared = set(pins) - {canonicalize_name(r.name) for r in reqs} - {canonicalize_name(m) for m in UNDECLARED}
    assert not undeclared, f"pinned in requirements.txt but declared nowhere in pyproject.toml: {sorted(undeclared)}"


def test_the_all_extra_names_every_other_extra():
    extras = _pyproject()["optional-dependencies"]
    (everything,) = extras["all"]
    assert Requirement(everything).name == "hbeo"
    assert Requirement(everything).extras == set(extras) - {"all"}
