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
    "averages": ["rovslam.camera", "rovslam.config", "rovslam.vision", "rovslam.slam", "rovslam.io", "rovslam.viz",
                 "rovslam.cli", "rovslam.pipeline", "rovslam.odometry", "rovslam.heading", "rovslam.sunlight"],
    "errors": ["rovslam.camera", "rovslam.config", "rovslam.vision", "rovslam.slam", "rovslam.io", "rovslam.viz",
               "rovslam.cli", "rovslam.pipeline", "rovslam.sim", "rovslam.eval"],
    "config": ["rovslam.cli", "rovslam.viz", "rovslam.pipeline", "rovslam.slam", "rovslam.vision", "rovslam.io"],
    "camera": ["rovslam.cli", "rovslam.viz", "rovslam.pipeline", "rovslam.slam", "rovslam.vision", "rovslam.io"],
    "vision": ["rovslam.slam", "rovslam.io", "rovslam.viz", "rovslam.cli", "rovslam.pipeline", "rovslam.sim"],
    "odometry": ["rovslam.io", "rovslam.viz", "rovslam.cli", "rovslam.pipeline", "rovslam.slam", "rovslam.sim"],
    "shutter": ["rovslam.io", "rovslam.viz", "rovslam.cli", "rovslam.pipeline", "rovslam.slam", "rovslam.sim"],
    "sunlight": ["rovslam.io", "rovslam.viz", "rovslam.cli", "rovslam.pipeline", "rovslam.slam", "rovslam.sim"],
    "heading": ["rovslam.io", "rovslam.viz", "rovslam.cli", "rovslam.pipeline", "rovslam.slam", "rovslam.vision"],
    "altitude": ["rovslam.io", "rovslam.viz", "rovslam.cli", "rovslam.pipeline", "rovslam.slam", "rovslam.vision"],
    "landmarks": ["rovslam.io", "rovslam.viz", "rovslam.cli", "rovslam.pipeline", "rovslam.slam"],
    "association": ["rovslam.io", "rovslam.viz", "rovslam.cli", "rovslam.pipeline", "rovslam.slam", "rovslam.vision"],
    "slam": ["rovslam.vision", "rovslam.io", "rovslam.viz", "rovslam.cli", "rovslam.pipeline", "rovslam.sim"],
    "pipeline": ["rovslam.cli", "rovslam.viz", "rovslam.sim", "rovslam.eval", "rovslam.batch"],
    "io": ["rovslam.slam.ekf", "rovslam.slam.gating", "rovslam.cli", "rovslam.viz", "rovslam.pipeline"],
    "sim": ["rovslam.slam", "rovslam.pipeline", "rovslam.cli", "rovslam.viz", "rovslam.eval"],
    "eval": ["rovslam.cli", "rovslam.viz"],
    "viz": ["rovslam.slam.ekf", "rovslam.slam.gating", "rovslam.cli"],
    "nav": ["rovslam.vision", "rovslam.io", "rovslam.viz", "rovslam.cli"],
    "navigate": ["rovslam.cli", "rovslam.batch"],
    "live": ["rovslam.cli", "rovslam.batch", "rovslam.sim", "rovslam.slam", "rovslam.vision", "rovslam.eval"],
}


def _part(path: Path) -> str:
    rel = path.relative_to(SRC)
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
