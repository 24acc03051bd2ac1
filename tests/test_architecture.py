"""The layering of docs/architecture.md, checked on the source: what each part never imports.

Every ``import rovslam...`` / ``from rovslam... import`` in a module counts, including the lazy
ones inside functions, so a rule cannot be broken by hiding an import in a function body.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

SRC = Path(__file__).resolve().parents[1] / "src" / "rovslam"

# part -> packages it must never import (docs/architecture.md, "Modules").
NEVER = {
    "averages": [
        "rovslam.camera",
        "rovslam.config",
        "rovslam.vision",
        "rovslam.slam",
        "rovslam.io",
        "rovslam.viz",
        "rovslam.cli",
        "rovslam.pipeline",
        "rovslam.sensor.odometry",
        "rovslam.sensor.heading",
        "rovslam.sensor.sunlight",
    ],
    "errors": [
        "rovslam.camera",
        "rovslam.config",
        "rovslam.vision",
        "rovslam.slam",
        "rovslam.io",
        "rovslam.viz",
        "rovslam.cli",
        "rovslam.pipeline",
        "rovslam.sim",
        "rovslam.eval",
    ],
    "config": [
        "rovslam.cli",
        "rovslam.viz",
        "rovslam.pipeline",
        "rovslam.slam",
        "rovslam.vision",
        "rovslam.io",
        "rovslam.sensor",
        "rovslam.mapping",
    ],
    "camera": [
        "rovslam.cli",
        "rovslam.viz",
        "rovslam.pipeline",
        "rovslam.slam",
        "rovslam.vision",
        "rovslam.io",
        "rovslam.sensor",
        "rovslam.mapping",
    ],
    "vision": [
        "rovslam.slam",
        "rovslam.io",
        "rovslam.viz",
        "rovslam.cli",
        "rovslam.pipeline",
        "rovslam.sim",
        "rovslam.sensor",
        "rovslam.mapping",
    ],
    "sensor": ["rovslam.io", "rovslam.viz", "rovslam.cli", "rovslam.pipeline", "rovslam.slam", "rovslam.sim"],
    "mapping": ["rovslam.io", "rovslam.viz", "rovslam.cli", "rovslam.pipeline", "rovslam.slam", "rovslam.sim"],
    "sensor.odometry": ["rovslam.io", "rovslam.viz", "rovslam.cli", "rovslam.pipeline", "rovslam.slam", "rovslam.sim"],
    "sensor.shutter": ["rovslam.io", "rovslam.viz", "rovslam.cli", "rovslam.pipeline", "rovslam.slam", "rovslam.sim"],
    "sensor.sunlight": ["rovslam.io", "rovslam.viz", "rovslam.cli", "rovslam.pipeline", "rovslam.slam", "rovslam.sim"],
    "sensor.heading": [
        "rovslam.io",
        "rovslam.viz",
        "rovslam.cli",
        "rovslam.pipeline",
        "rovslam.slam",
        "rovslam.vision",
    ],
    "sensor.altitude": [
        "rovslam.io",
        "rovslam.viz",
        "rovslam.cli",
        "rovslam.pipeline",
        "rovslam.slam",
        "rovslam.vision",
    ],
    "mapping.landmarks": ["rovslam.io", "rovslam.viz", "rovslam.cli", "rovslam.pipeline", "rovslam.slam"],
    "mapping.association": [
        "rovslam.io",
        "rovslam.viz",
        "rovslam.cli",
        "rovslam.pipeline",
        "rovslam.slam",
        "rovslam.vision",
    ],
    "slam": [
        "rovslam.vision",
        "rovslam.io",
        "rovslam.viz",
        "rovslam.cli",
        "rovslam.pipeline",
        "rovslam.sim",
        "rovslam.sensor",
        "rovslam.mapping",
    ],
    "pipeline": ["rovslam.cli", "rovslam.viz", "rovslam.sim", "rovslam.eval", "rovslam.batch"],
    "data": [
        "rovslam.config",
        "rovslam.camera",
        "rovslam.vision",
        "rovslam.slam",
        "rovslam.io",
        "rovslam.viz",
        "rovslam.cli",
        "rovslam.pipeline",
        "rovslam.sim",
        "rovslam.eval",
        "rovslam.nav",
    ],
    "core": [
        "rovslam.config",
        "rovslam.vision",
        "rovslam.slam",
        "rovslam.io",
        "rovslam.viz",
        "rovslam.cli",
        "rovslam.pipeline",
        "rovslam.sim",
        "rovslam.eval",
        "rovslam.nav",
        "rovslam.sensor",
        "rovslam.mapping",
    ],
    "process": [
        "rovslam.camera",
        "rovslam.config",
        "rovslam.vision",
        "rovslam.slam",
        "rovslam.io",
        "rovslam.viz",
        "rovslam.cli",
        "rovslam.pipeline",
        "rovslam.sim",
        "rovslam.eval",
        "rovslam.batch",
        "rovslam.nav",
        "rovslam.live",
        "rovslam.sensor",
        "rovslam.mapping",
    ],
    "tallies": [
        "rovslam.cli",
        "rovslam.viz",
        "rovslam.sim",
        "rovslam.eval",
        "rovslam.batch",
        "rovslam.slam",
        "rovslam.vision",
    ],
    "io": ["rovslam.slam.ekf", "rovslam.slam.gating", "rovslam.cli", "rovslam.viz", "rovslam.pipeline", "rovslam.nav"],
    "sim": ["rovslam.slam", "rovslam.pipeline", "rovslam.cli", "rovslam.viz", "rovslam.eval"],
    "eval": ["rovslam.cli", "rovslam.viz"],
    "viz": ["rovslam.slam.ekf", "rovslam.slam.gating", "rovslam.cli"],
    "nav": ["rovslam.vision", "rovslam.io", "rovslam.viz", "rovslam.cli"],
    "navigate": ["rovslam.cli", "rovslam.batch"],
    "live": ["rovslam.cli", "rovslam.batch", "rovslam.sim", "rovslam.slam", "rovslam.vision", "rovslam.eval"],
}


GROUPS = ("sensor", "mapping")  # packages that group stages: each of their modules is a part of its own


def _part(path: Path) -> str:
    rel = path.relative_to(SRC)
    if rel.parts[0] in GROUPS and len(rel.parts) > 1 and rel.parts[1] != "__init__.py":
        return f"{rel.parts[0]}.{rel.parts[1].removesuffix('.py')}"
    return rel.parts[0].removesuffix(".py")


def _imports(path: Path) -> set[str]:
    tree = ast.parse(path.read_text(encoding="utf-8"))
    out = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.add(node.module)
            out.update(f"{node.module}.{a.name}" for a in node.names)
    return {m for m in out if m.startswith("rovslam")}


MODULES = sorted(p for p in SRC.rglob("*.py"))


@pytest.mark.parametrize("path", MODULES, ids=lambda p: str(p.relative_to(SRC)))
def test_no_module_imports_what_its_layer_must_not(path):
    forbidden = NEVER.get(_part(path), [])
    bad = sorted(m for m in _imports(path) if any(m == f or m.startswith(f + ".") for f in forbidden))
    assert not bad, f"{path.relative_to(SRC)} imports {bad}, which its layer never imports (docs/architecture.md)"


def test_only_the_cli_imports_the_batch_runner():
    users = [p for p in MODULES if any(m.startswith("rovslam.batch") for m in _imports(p))]
    assert all(_part(p) in ("cli", "batch") for p in users), users


def test_the_rules_cover_every_part_of_the_package():
    parts = {_part(p) for p in MODULES} - {"__init__", "__main__", "cli", "runner", "batch"}
    assert parts <= set(NEVER), f"add the new parts to NEVER and to docs/architecture.md: {parts - set(NEVER)}"


def _module_name(path: Path) -> str:
    rel = path.relative_to(SRC.parent).with_suffix("")
    name = ".".join(rel.parts)
    return name.removesuffix(".__init__")


def _import_graph() -> dict[str, set[str]]:
    """Module -> the package's modules it imports (lazy imports included; a package's own
    ``__init__`` re-exporting its submodules is not an edge)."""
    names = {_module_name(p): p for p in MODULES}
    graph = {}
    for name, path in names.items():
        deps = set()
        for m in _imports(path):
            while m and m not in names:  # "rovslam.io.sequence.Frame" -> "rovslam.io.sequence"
                m = m.rpartition(".")[0]
            if m and m != name and not m.startswith(name + "."):
                deps.add(m)
        graph[name] = deps
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components of more than one module (Tarjan)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                found.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def test_no_import_circle():
    assert _cycles(_import_graph()) == []


def test_the_circle_check_finds_a_circle():
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert _cycles(graph) == [["a", "b", "c"]]


def test_input_never_depends_on_navigation():
    io_modules = [p for p in MODULES if _part(p) == "io"]
    assert io_modules
    users = [str(p.relative_to(SRC)) for p in io_modules if any(m.startswith("rovslam.nav") for m in _imports(p))]
    assert users == []


MAX_MODULE_LINES, MAX_CLASS_LINES, MAX_FUNCTION_LINES = 800, 400, 100


def _oversized(path: Path) -> list[str]:
    """What in ``path`` is over the size limits (docstrings and comments counted, as the code reads)."""
    text = path.read_text(encoding="utf-8")
    found = []
    if len(text.splitlines()) > MAX_MODULE_LINES:
        found.append(f"module {len(text.splitlines())} lines")
    for node in ast.walk(ast.parse(text)):
        lines = getattr(node, "end_lineno", 0) - getattr(node, "lineno", 0) + 1
        if isinstance(node, ast.ClassDef) and lines > MAX_CLASS_LINES:
            found.append(f"class {node.name} {lines} lines")
        if isinstance(node, ast.FunctionDef | ast.AsyncFunctionDef) and lines > MAX_FUNCTION_LINES:
            found.append(f"function {node.name} {lines} lines")
    return found


def test_no_module_class_or_function_is_over_its_size_limit():
    over = {str(p.relative_to(SRC)): _oversized(p) for p in MODULES}
    assert {k: v for k, v in over.items() if v} == {}


def test_the_size_check_sees_a_long_function(tmp_path):
    body = "\n".join(f"    x{i} = {i}" for i in range(MAX_FUNCTION_LINES))
    (tmp_path / "m.py").write_text(f"def f():\n{body}\n")
    assert _oversized(tmp_path / "m.py") == [f"function f {MAX_FUNCTION_LINES + 1} lines"]
