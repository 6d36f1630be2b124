"""The house rule "no class over 15 methods", for all the project's code (the library, the
renderer, the app, benchmarks and scripts): a class that grows past it holds more than one idea
and is split into values and functions."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
MAX_METHODS = 15


def oversized_classes(root: Path) -> list[str]:
    """'path:line Class (N methods)' for every class under ``root`` with more than MAX_METHODS."""
    found = []
    for path in sorted(root.rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
            if isinstance(node, ast.ClassDef):
                methods = [n for n in node.body if isinstance(n, (ast.FunctionDef, ast.AsyncFunctionDef))]
                if len(methods) > MAX_METHODS:
                    found.append(f"{path.relative_to(root.parent)}:{node.lineno} {node.name} ({len(methods)} methods)")
    return found


@pytest.mark.parametrize("folder", ["inceptiongs", "renderer", "app", "benchmarks", "scripts"])
def test_no_class_has_more_than_15_methods(folder):
    assert oversized_classes(ROOT / folder) == []


def test_the_check_counts_methods_of_nested_classes_too(tmp_path):
    package = tmp_path / "pkg"
    package.mkdir()
    body = "\n".join(f"        def m{i}(self): pass" for i in range(MAX_METHODS + 1))
    (package / "big.py").write_text(f"def f():\n    class Big:\n{body}\n")
    (package / "small.py").write_text("class Small:\n    def m(self): pass\n")
    assert oversized_classes(package) == ["pkg/big.py:2 Big (16 methods)"]
