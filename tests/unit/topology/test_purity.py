"""The topology core stays pure numpy: no transport, files, clocks, plotting or simulator."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3] / "fusion_center" / "topology"
FORBIDDEN = {
    "zenoh",
    "msgpack",
    "mcap",
    "serial",
    "time",
    "datetime",
    "socket",
    "threading",
    "matplotlib",
    "sim_nodes",
    "uwbnet",
    "pathlib",
    "os",
}


@pytest.mark.parametrize("path", sorted(ROOT.glob("*.py")), ids=lambda p: p.name)
def test_module_imports_nothing_impure(path: Path) -> None:
    imported = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            imported |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            imported.add(node.module.split(".")[0])
    assert not imported & FORBIDDEN, f"{path.name} imports {sorted(imported & FORBIDDEN)}"
