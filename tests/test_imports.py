"""The import graph's rules (scripts/check_imports.py), and that the checker itself catches what
it is meant to."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts" / "check_imports.py"


def load_checker():
    spec = importlib.util.spec_from_file_location("check_imports", SCRIPT)
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # dataclasses look their module up while the class is made
    spec.loader.exec_module(module)
    return module


def test_project_imports_have_no_circle_no_upward_layer_and_no_private_names():
    result = subprocess.run([sys.executable, str(SCRIPT)], capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stdout + result.stderr


def test_checker_finds_a_circle_through_function_level_imports():
    checker = load_checker()
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert checker.find_cycles(graph) == [["a", "b", "c"]]
    assert checker.find_cycles({"a": {"b"}, "b": set()}) == []


def test_checker_reads_imports_inside_functions_and_resolves_relative_ones(tmp_path):
    checker = load_checker()
    source = tmp_path / "mod.py"
    source.write_text("def f():\n    from ..train.step import train_step\n    from . import losses\n")
    imports = checker.imports_of(source, "inceptiongs.bootstrap.refine", False)
    assert {(i.target, i.names) for i in imports} == {("inceptiongs.train.step", ("train_step",)),
                                                      ("inceptiongs.bootstrap", ("losses",))}


def test_layers_run_one_way():
    checker = load_checker()
    assert checker.layer("inceptiongs.train.step") == checker.LIBRARY
    assert checker.layer("inceptiongs.renderer.splats") == checker.RENDERER
    assert checker.layer("inceptiongs.app.viewer") == checker.APP
    assert checker.LIBRARY in checker.ALLOWED[checker.RENDERER]
    assert checker.RENDERER not in checker.ALLOWED[checker.LIBRARY]
    assert checker.APP not in checker.ALLOWED[checker.RENDERER]
