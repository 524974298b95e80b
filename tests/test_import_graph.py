"""The house layout, checked on the source: every `import` of tapcell modules, at module level,
inside functions and under TYPE_CHECKING alike, read with `ast` (nothing is imported)."""

from __future__ import annotations

import ast
import subprocess
import sys
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parents[1] / "src" / "tapcell"
# The math, and the independent tap generator (which must share no code with the simulator).
PURE = ("tapcell.tap", "tapcell.mesh", "tapcell.filters", "tapcell.scale", "tapcell.taplab")
ABOVE_THE_MATH = ("tapcell.host", "tapcell.extras", "tapcell.tools", "tapcell.sim")
MAY_IMPORT_SIM = ("tapcell.host", "tapcell.tools", "tapcell.sim")


def module_name(path: Path) -> str:
    parts = list(path.relative_to(PACKAGE.parent).with_suffix("").parts)
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


MODULES = {module_name(path): path for path in PACKAGE.rglob("*.py")}


def in_package(name: str, packages: tuple[str, ...]) -> bool:
    return any(name == p or name.startswith(p + ".") for p in packages)


def resolve(name: str) -> str | None:
    """The tapcell module a dotted name lands in (a name inside a module: that module)."""
    while name and name not in MODULES:
        name = name.rpartition(".")[0]
    return name or None


def imports_of(module: str) -> set[str]:
    path = MODULES[module]
    found: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            found.update(resolve(alias.name) for alias in node.names if alias.name.startswith("tapcell"))
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                package = module if path.name == "__init__.py" else module.rpartition(".")[0]
                for _ in range(node.level - 1):
                    package = package.rpartition(".")[0]
                base = f"{package}.{base}" if base else package
            if base.startswith("tapcell"):
                # `from package import module` imports the module; `from module import name`, the module.
                found.update(resolve(f"{base}.{alias.name}") for alias in node.names)
    found.discard(None)
    found.discard(module)
    return found


GRAPH = {module: imports_of(module) for module in MODULES}


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(node: str) -> None:
        index[node] = low[node] = len(index)
        stack.append(node)
        on_stack.add(node)
        for target in sorted(graph[node]):
            if target not in index:
                visit(target)
                low[node] = min(low[node], low[target])
            elif target in on_stack:
                low[node] = min(low[node], index[target])
        if low[node] == index[node]:
            component = []
            while True:
                member = stack.pop()
                on_stack.discard(member)
                component.append(member)
                if member == node:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for node in sorted(graph):
        if node not in index:
            visit(node)
    return found


def test_the_graph_sees_function_level_imports():
    # The reader must see what an import inside a function pulls in, or a cycle could hide there.
    graph = {"a": {"b"}, "b": {"a"}, "c": {"a"}}
    assert cycles(graph) == [["a", "b"]]
    assert "tapcell.sim.scale_sensor" in GRAPH["tapcell.sim.printer"]  # imported inside add_sensor
    assert "tapcell.tap" in GRAPH["tapcell.extras.load_cell_probe.calibration"]  # inside fit_pooled_contact_onset
    assert GRAPH["tapcell.tap.classifiers"] >= {"tapcell.tap.context", "tapcell.tap.model"}


def test_no_import_cycles_between_files():
    assert cycles(GRAPH) == []


@pytest.mark.parametrize("package", PURE)
def test_the_math_imports_nothing_above_it(package):
    wrong = sorted(f"{module} -> {target}" for module, targets in GRAPH.items() if in_package(module, (package,))
                   for target in targets if in_package(target, ABOVE_THE_MATH))
    assert wrong == []


def test_only_the_host_the_tools_and_the_simulator_import_the_simulator():
    wrong = sorted(f"{module} -> {target}" for module, targets in GRAPH.items()
                   if not in_package(module, MAY_IMPORT_SIM)
                   for target in targets if in_package(target, ("tapcell.sim",)))
    assert wrong == []


def test_the_tap_analysis_imports_with_numpy_alone():
    code = ("import sys, tapcell.tap; "
            "print(sorted({m.split('.')[0] for m in sys.modules} & {'scipy', 'matplotlib', 'jinja2', 'rich', 'cffi'}))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"
