#!/usr/bin/env python3
"""Checks the project's import graph: no import circles, one-way layers, no private names
borrowed across modules.

Every import counts, also those inside functions (a function-level import may defer a heavy
module, never hide a circle). Rules:

1. No circle among the project's modules. Importing ``a.b.c`` also runs ``a`` and ``a.b``
   (their ``__init__``), so those count as imported too.
2. Layers run one way: app -> renderer -> library. The library (``inceptiongs`` outside
   ``inceptiongs.app`` and ``inceptiongs.renderer``) imports neither; the renderer does not
   import the app.
3. Inside the library, packages run one way too, in the order the data flows (LIBRARY_ORDER,
   the table docs/design.md shows): a module imports only from its own layer or the layers
   before it. A package's ``__init__`` imports nothing of the project, so importing a package
   costs no layer.
4. ``from X import _name`` is refused when X is another project module: a private name is
   private to its module. Tests, benchmarks and scripts are held to this too.
5. Stage II's experimental variants (SEALED) are imported only from inside their folder: the
   installed code reaches them by name through one door (inceptiongs/bootstrap/variants.py,
   importlib), so the default path never loads them. Tests and benchmarks of a variant may
   import it.

    python3 scripts/check_imports.py          # prints the problems, exit status 1 if any
"""

from __future__ import annotations

import ast
import sys
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
# The design card's folders and the import names they are installed under (pyproject's package-dir).
PACKAGE_DIRS = {"inceptiongs": "inceptiongs", "app": "inceptiongs.app", "renderer": "inceptiongs.renderer",
                "shaders": "inceptiongs.shaders"}
# Code that is not installed but must still keep to rule 3; its modules are named by path.
LOOSE_DIRS = ("tests", "benchmarks", "scripts")
LIBRARY, RENDERER, APP = "inceptiongs", "inceptiongs.renderer", "inceptiongs.app"
# The library's layers, first to last: a module may import from its own layer and the ones above it
# in this list. A module belongs to the layer with the longest prefix that names it.
LIBRARY_ORDER = (
    ("foundation", ("inceptiongs.constants", "inceptiongs.errors", "inceptiongs.threads", "inceptiongs.live",
                    "inceptiongs.stop_signals", "inceptiongs.camera", "inceptiongs.pinhole", "inceptiongs.gaussians",
                    "inceptiongs.io")),
    ("scene", ("inceptiongs.scene",)),
    ("rasterizer", ("inceptiongs.rasterizer",)),
    ("lod", ("inceptiongs.lod",)),
    ("measures", ("inceptiongs.evaluation.metrics", "inceptiongs.evaluation.networks", "inceptiongs.evaluation.lpips_net",
                  "inceptiongs.evaluation.scoring", "inceptiongs.evaluation.protocols",
                  "inceptiongs.evaluation.coverage", "inceptiongs.evaluation.report")),
    ("runs", ("inceptiongs.runs",)),
    ("train", ("inceptiongs.train",)),
    ("prior", ("inceptiongs.prior",)),
    ("bootstrap", ("inceptiongs.bootstrap",)),
    ("results", ("inceptiongs.evaluation",)),
    ("commands", ("inceptiongs.commands", "inceptiongs.cli", "inceptiongs.__main__")),
)


@dataclass(frozen=True)
class Import:
    importer: str       # module doing the import
    target: str         # absolute module imported (or the module a name is imported from)
    names: tuple        # names taken with "from target import ..." (empty for "import target")
    line: int


def module_name(path: Path) -> tuple[str, bool]:
    """File -> (dotted module name, is_package)."""
    rel = path.relative_to(ROOT).with_suffix("")
    parts = list(rel.parts)
    prefix = PACKAGE_DIRS.get(parts[0])
    # Tests, benchmarks and scripts run with their own folder on sys.path: imported by bare name.
    dotted = prefix.split(".") + parts[1:] if prefix else parts[-1:]
    is_package = dotted[-1] == "__init__"
    if is_package:
        dotted = dotted[:-1]
    return ".".join(dotted), is_package


def project_files() -> list[Path]:
    files = []
    for folder in (*PACKAGE_DIRS, *LOOSE_DIRS):
        files += sorted((ROOT / folder).rglob("*.py"))
    return [f for f in files if "__pycache__" not in f.parts]


def imports_of(path: Path, module: str, is_package: bool) -> list[Import]:
    tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
    package = module if is_package else module.rpartition(".")[0]
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            found += [Import(module, alias.name, (), node.lineno) for alias in node.names]
        elif isinstance(node, ast.ImportFrom):
            if node.level:
                base = package.split(".")
                base = base[: len(base) - (node.level - 1)]
                target = ".".join(base + ([node.module] if node.module else []))
            else:
                target = node.module or ""
            found.append(Import(module, target, tuple(a.name for a in node.names), node.lineno))
    return found


def edges(imp: Import, modules: set[str]) -> set[str]:
    """The project modules an import runs: the target, its parent packages, and any
    ``from package import submodule``."""
    out = set()
    candidates = [imp.target] + [f"{imp.target}.{name}" for name in imp.names]
    for candidate in candidates:
        parts = candidate.split(".")
        for i in range(1, len(parts) + 1):
            prefix = ".".join(parts[:i])
            if prefix in modules:
                out.add(prefix)
    out.discard(imp.importer)
    return out


def layer(module: str) -> str | None:
    for name in (APP, RENDERER):
        if module == name or module.startswith(name + "."):
            return name
    if module == LIBRARY or module.startswith(LIBRARY + "."):
        return LIBRARY if not module.startswith("inceptiongs.shaders") else None
    return None


def library_layer(module: str) -> int | None:
    """The index in LIBRARY_ORDER of ``module``'s layer (None: not in the table)."""
    best, best_len = None, -1
    for index, (_name, prefixes) in enumerate(LIBRARY_ORDER):
        for prefix in prefixes:
            if (module == prefix or module.startswith(prefix + ".")) and len(prefix) > best_len:
                best, best_len = index, len(prefix)
    return best


def order_problem(module: str, target: str, packages: set[str]) -> str | None:
    """Why ``module`` importing ``target`` goes against LIBRARY_ORDER (None: it does not)."""
    if target in packages:
        return None   # a package's __init__ imports nothing (checked on its own)
    source_index, target_index = library_layer(module), library_layer(target)
    if source_index is None or target_index is None or target_index <= source_index:
        return None
    return (f"{LIBRARY_ORDER[source_index][0]} layer imports {target} ({LIBRARY_ORDER[target_index][0]} layer); "
            f"the library's layers run {' -> '.join(name for name, _ in LIBRARY_ORDER)}")


ALLOWED = {LIBRARY: {LIBRARY}, RENDERER: {LIBRARY, RENDERER}, APP: {LIBRARY, RENDERER, APP}}
# Packages only their own modules import (rule 5).
SEALED = ("inceptiongs.bootstrap.experimental",)


def inside(module: str, package: str) -> bool:
    return module == package or module.startswith(package + ".")


def sealed_problem(module: str, target: str) -> str | None:
    """Why ``module`` importing ``target`` breaks rule 5 (None: it does not)."""
    for package in SEALED:
        if inside(target, package) and not inside(module, package):
            return (f"{module} imports {target}: {package} is reached only by name, through "
                    f"inceptiongs/bootstrap/variants.py")
    return None


def find_cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan, iterative)."""
    index, low, on_stack, stack, result, counter = {}, {}, set(), [], [], [0]
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = counter[0]; counter[0] += 1
        stack.append(root); on_stack.add(root)
        while work:
            node, children = work[-1]
            advanced = False
            for child in children:
                if child not in index:
                    index[child] = low[child] = counter[0]; counter[0] += 1
                    stack.append(child); on_stack.add(child)
                    work.append((child, iter(sorted(graph.get(child, ())))))
                    advanced = True
                    break
                if child in on_stack:
                    low[node] = min(low[node], index[child])
            if advanced:
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop(); on_stack.discard(member); component.append(member)
                    if member == node:
                        break
                if len(component) > 1:
                    result.append(sorted(component))
    return result


def check(root: Path | None = None) -> list[str]:
    """Every problem in the project at ``root`` (default: this checkout), one line each."""
    global ROOT
    if root is not None:
        ROOT = Path(root)
    files = project_files()
    named = {f: module_name(f) for f in files}
    installed = {name for f, (name, _) in named.items() if f.relative_to(ROOT).parts[0] in PACKAGE_DIRS}
    all_modules = {name for name, _ in named.values()}
    packages = {name for f, (name, is_package) in named.items() if is_package and name in installed}
    problems = []
    graph: dict[str, set[str]] = {name: set() for name in installed}
    for path, (module, is_package) in named.items():
        where = path.relative_to(ROOT)
        for imp in imports_of(path, module, is_package):
            targets = edges(imp, all_modules)
            for name in imp.names:
                if name.startswith("_") and not name.startswith("__") and imp.target in all_modules \
                        and imp.target != module:
                    problems.append(f"{where}:{imp.line}: private name {name} imported from {imp.target}")
            if module not in installed:
                continue
            if is_package and targets & installed and layer(module) is not None:
                problems.append(f"{where}:{imp.line}: a package's __init__ imports nothing of the project "
                                f"(it imports {imp.target})")
            # One line per import, also for ``from package import experimental``.
            sealed = [why for candidate in (imp.target, *(f"{imp.target}.{n}" for n in imp.names))
                      if (why := sealed_problem(module, candidate))]
            problems += [f"{where}:{imp.line}: {why}" for why in sealed[:1]]
            for target in targets & installed:
                if layer(module) == LIBRARY and layer(target) == LIBRARY:
                    why = order_problem(module, target, packages)
                    if why:
                        problems.append(f"{where}:{imp.line}: {why}")
                graph[module].add(target)
                source_layer, target_layer = layer(module), layer(target)
                if source_layer and target_layer and target_layer not in ALLOWED[source_layer]:
                    problems.append(f"{where}:{imp.line}: {source_layer} layer imports {target} "
                                    f"({target_layer} layer); layers run app -> renderer -> library")
    for component in find_cycles(graph):
        chain = " <-> ".join(component)
        problems.append(f"import circle: {chain}")
    return problems


def main() -> int:
    problems = check()
    for problem in problems:
        print(problem)
    if problems:
        print(f"{len(problems)} import problem(s)", file=sys.stderr)
        return 1
    print("imports: no circles, layers one way (the library's in LIBRARY_ORDER), no private names across modules, "
          "experimental variants only through their door")
    return 0


if __name__ == "__main__":
    sys.exit(main())
