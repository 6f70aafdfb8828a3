"""The package's layers, read from its source (docs/architecture.md): no import runs back up a
layer, the computation packages open no files, library errors name parameters, not flags,
functions stay short, and ``import msleak`` has no side effect."""

from __future__ import annotations

import ast
import re
import subprocess
import sys
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[2] / "msleak"

#: bottom to top: a module may import its own package and the packages of lower layers
LAYERS = [
    ("msleak.errors", "msleak.constants", "msleak.conventions", "msleak._callable"),
    ("msleak.io", "msleak._everybeam"),
    ("msleak.sky", "msleak.beam", "msleak.telescope"),
    ("msleak.predict", "msleak.ps"),
    ("msleak.leakage",),
    ("msleak.adapters", "msleak.plot", "msleak.parallel"),
    ("msleak.verbs",),
    ("msleak.study",),
    ("msleak.cli",),
    ("msleak.__main__",),
]
#: (importer, imported) of one layer: the only imports between packages of a layer
SAME_LAYER = {("msleak.conventions", "msleak.errors"), ("msleak.telescope", "msleak.beam"),
              ("msleak.io", "msleak._everybeam")}

COMPUTATION = ("sky", "beam", "predict", "ps", "leakage")
FILE_MODULES = ("msleak.io", "casacore", "h5py", "astropy.io.fits", "matplotlib", "msleak.plot")
#: module -> why it imports one of FILE_MODULES (listed in docs/architecture.md)
FILE_EXCEPTIONS = {
    "msleak.beam.coords": "casacore measures",
}


def _modules():
    for path in sorted(PACKAGE.rglob("*.py")):
        parts = path.relative_to(PACKAGE.parent).with_suffix("").parts
        name = ".".join(parts[:-1] if parts[-1] == "__init__" else parts)
        yield name, path, ast.parse(path.read_text(), filename=str(path))


def _imports(name: str, path: Path, tree: ast.AST):
    """(line, imported module) of every import in ``tree``, relative ones resolved."""
    package = name if path.name == "__init__.py" else name.rpartition(".")[0]
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                yield node.lineno, alias.name
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[:len(package.split(".")) - node.level + 1]
                base = ".".join(anchor + ([base] if base else []))
            yield node.lineno, base
            for alias in node.names:
                yield node.lineno, f"{base}.{alias.name}"


def _unit(module: str) -> str | None:
    """The layer unit (package or top-level module) of an msleak module."""
    for layer in LAYERS:
        for unit in layer:
            if module == unit or module.startswith(unit + "."):
                return unit
    return None


def _rank(unit: str) -> int:
    return next(i for i, layer in enumerate(LAYERS) if unit in layer)


def test_every_module_has_a_layer():
    missing = [name for name, _, _ in _modules() if name != "msleak" and _unit(name) is None]
    assert not missing, f"modules in no layer of LAYERS: {missing}"


def test_no_import_runs_back_up_a_layer():
    wrong = []
    for name, path, tree in _modules():
        here = _unit(name)
        if here is None:
            continue
        for line, imported in _imports(name, path, tree):
            there = _unit(imported)
            if there is None or there == here:
                continue
            if _rank(there) > _rank(here) or (_rank(there) == _rank(here)
                                              and (here, there) not in SAME_LAYER):
                wrong.append(f"{path.relative_to(PACKAGE.parent)}:{line} {name} -> {imported}")
    assert not wrong, "imports that run back up a layer:\n" + "\n".join(wrong)


def test_computation_packages_open_no_files():
    wrong = []
    for name, path, tree in _modules():
        if name.split(".")[1:2] not in [[p] for p in COMPUTATION]:
            continue
        if name in FILE_EXCEPTIONS:
            continue
        for line, imported in _imports(name, path, tree):
            if any(imported == m or imported.startswith(m + ".") for m in FILE_MODULES):
                wrong.append(f"{path.relative_to(PACKAGE.parent)}:{line} imports {imported}")
    assert not wrong, "\n".join(wrong)


def test_file_exceptions_are_few_and_documented():
    assert len(FILE_EXCEPTIONS) <= 3
    text = (PACKAGE.parent / "docs" / "architecture.md").read_text()
    for module in FILE_EXCEPTIONS:
        assert f"`{module}`" in text, module


def _strings(node: ast.AST) -> str:
    return " ".join(n.value for n in ast.walk(node)
                    if isinstance(n, ast.Constant) and isinstance(n.value, str))


def test_library_errors_name_parameters_not_flags():
    """Only the command line spells flags (it maps parameter names to them,
    msleak/cli/_flags.py); a message may quote a whole command in backticks."""
    wrong = []
    for name, path, tree in _modules():
        if name.startswith("msleak.cli"):
            continue
        for node in ast.walk(tree):
            if isinstance(node, ast.Raise) and node.exc is not None:
                text = re.sub(r"`msleak [^`]*`", "", _strings(node.exc))
                if re.search(r"(?<![\w-])--[a-z]", text):
                    wrong.append(f"{path.relative_to(PACKAGE.parent)}:{node.lineno}")
    assert not wrong, "raises that name a --flag:\n" + "\n".join(wrong)


def _numba_kernel(node: ast.FunctionDef) -> bool:
    names = {ast.unparse(d).split("(")[0].rpartition(".")[2] for d in node.decorator_list}
    return bool(names & {"njit", "jit", "vectorize", "guvectorize"})


def test_functions_stay_under_80_lines():
    long = []
    for name, path, tree in _modules():
        for node in ast.walk(tree):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                lines = node.end_lineno - node.lineno + 1
                if lines > 80 and not _numba_kernel(node):
                    long.append(f"{path.relative_to(PACKAGE.parent)}:{node.lineno} "
                                f"{node.name} ({lines} lines)")
    assert not long, "\n".join(long)


def test_import_msleak_has_no_side_effect():
    code = ("import sys, msleak; "
            "print(sorted(m for m in sys.modules if m.startswith(('msleak.', 'casacore'))))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          check=True, timeout=120)
    assert done.stdout.strip() == "['msleak._callable', 'msleak.errors']" or \
        done.stdout.strip() == "['msleak.errors']", done.stdout


@pytest.mark.parametrize("package", ["msleak.predict", "msleak.leakage"])
def test_callable_packages_import_no_verb(package):
    code = (f"import sys, {package}; "
            "print([m for m in sys.modules if m.startswith(('msleak.verbs', 'msleak.io'))])")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          check=True, timeout=120)
    assert done.stdout.strip() == "[]", done.stdout
