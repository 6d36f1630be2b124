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


def copy_of_the_project(tmp_path: Path) -> Path:
    """The installed folders copied, so a test can plant an import without touching the checkout."""
    import shutil

    copy = tmp_path / "project"
    for folder in ("inceptiongs", "app", "renderer", "shaders"):
        shutil.copytree(ROOT / folder, copy / folder, ignore=shutil.ignore_patterns("__pycache__"))
    for folder in ("tests", "benchmarks", "scripts"):
        (copy / folder).mkdir()
    return copy


def test_checker_fails_on_an_import_against_the_library_order(tmp_path):
    checker = load_checker()
    copy = copy_of_the_project(tmp_path)
    assert checker.check(copy) == []
    hashgrid = copy / "inceptiongs" / "prior" / "hashgrid.py"
    hashgrid.write_text(hashgrid.read_text() + "\n\ndef f():\n    from ..bootstrap.warp import warp_to_view\n")
    problems = checker.check(copy)
    assert len(problems) == 1 and "prior layer imports inceptiongs.bootstrap.warp (bootstrap layer)" in problems[0]
    # Run-level evaluation sits above the bootstrap; the metrics sit below training.
    step = copy / "inceptiongs" / "train" / "losses.py"
    step.write_text(step.read_text() + "\n\ndef g():\n    from ..evaluation.run import evaluate_run\n")
    assert any("train layer imports inceptiongs.evaluation.run (results layer)" in p for p in checker.check(copy))


def test_checker_fails_on_a_package_init_that_imports(tmp_path):
    checker = load_checker()
    copy = copy_of_the_project(tmp_path)
    init = copy / "inceptiongs" / "runs" / "__init__.py"
    init.write_text(init.read_text() + "\nfrom .config import TrainConfig\n")
    assert any("a package's __init__ imports nothing" in p for p in checker.check(copy))


def test_every_library_module_has_a_place_in_the_order():
    checker = load_checker()
    for path in checker.project_files():
        module, _ = checker.module_name(path)
        if checker.layer(module) == checker.LIBRARY and module != checker.LIBRARY:
            assert checker.library_layer(module) is not None, f"{path}: add its package to LIBRARY_ORDER"


def test_checker_fails_on_an_import_of_an_experimental_variant_outside_its_folder(tmp_path):
    """The variants are reached by name through bootstrap/variants.py; a direct import, even one
    deferred into a function, is refused (inside experimental/ they may import each other)."""
    checker = load_checker()
    copy = copy_of_the_project(tmp_path)
    refine = copy / "inceptiongs" / "bootstrap" / "refine.py"
    refine.write_text(refine.read_text() + "\n\ndef f():\n    from .experimental.align import align_warp\n")
    problems = checker.check(copy)
    assert len(problems) == 1 and "inceptiongs.bootstrap.experimental.align" in problems[0] \
        and "variants.py" in problems[0], problems
    refine.write_text(refine.read_text().replace("from .experimental.align import align_warp", "pass"))
    informative = copy / "inceptiongs" / "bootstrap" / "experimental" / "informative.py"
    assert "from .photo_supervision import" in informative.read_text() and checker.check(copy) == []
