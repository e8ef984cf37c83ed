"""The package's layers (docs/decisions/0014-layered-packages.md): the import contracts of
pyproject.toml hold, an import inside a function says why it is there, and a module over
600 lines says why it is one module."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

from .conftest import ROOT

PACKAGE = ROOT / "kali_daemons"
LONG = 600  # lines: past this a module says in its docstring why it is one ("on purpose")


def modules() -> list[Path]:
    return sorted(p for p in PACKAGE.rglob("*.py") if "__pycache__" not in p.parts)


def test_the_import_contracts_hold() -> None:
    """lint-imports (import-linter on grimp's graph): the layers, the controller never
    importing the plant, no circle inside a package."""
    lint = Path(sys.executable).with_name("lint-imports")
    r = subprocess.run(
        [str(lint), "--no-cache", "--no-logo"], cwd=ROOT, capture_output=True, text=True
    )
    assert r.returncode == 0, r.stdout + r.stderr


def silent_imports(path: Path) -> list[str]:
    """The imports inside functions of ``path`` that carry no comment on their line (nor on
    the import just before them, for a group)."""
    text = path.read_text()
    lines = text.splitlines()
    found: list[str] = []

    def walk(node: ast.AST, inside: bool) -> None:
        for child in ast.iter_child_nodes(node):
            nested = inside or isinstance(child, ast.FunctionDef | ast.AsyncFunctionDef)
            if inside and isinstance(child, ast.Import | ast.ImportFrom):
                line, before = lines[child.lineno - 1], lines[child.lineno - 2]
                grouped = before.lstrip().startswith(("import ", "from ")) and "#" in before
                if "#" not in line and not grouped:
                    found.append(f"{path.relative_to(ROOT)}:{child.lineno}: {line.strip()}")
            walk(child, nested)

    walk(ast.parse(text), False)
    return found


def test_an_import_inside_a_function_says_why() -> None:
    """A function-level import is there on purpose (a heavy or optional library), never to
    dodge an import circle, and its comment says so."""
    silent = [s for path in modules() for s in silent_imports(path)]
    assert not silent, "imports inside functions without a reason:\n" + "\n".join(silent)


def test_a_long_module_says_why_it_is_one() -> None:
    long = []
    for path in modules():
        text = path.read_text()
        n = text.count("\n")
        doc = ast.get_docstring(ast.parse(text)) or ""
        if n > LONG and "on purpose" not in doc:
            long.append(f"{path.relative_to(ROOT)}: {n} lines")
    assert not long, "modules over 600 lines without a reason in the docstring:\n" + "\n".join(
        long
    )
