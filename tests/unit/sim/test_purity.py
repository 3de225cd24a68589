"""The simulator core stays pure: no transport, serialisation, recording or clock imports."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3] / "sim_nodes"
FORBIDDEN = {"zenoh", "msgpack", "mcap", "serial", "time", "datetime", "socket", "threading"}
PURE = [
    "radar.py",
    "network.py",
    "scene.py",
    *(p.name for p in (ROOT / "channel").glob("*.py")),
]


@pytest.mark.parametrize("name", PURE)
def test_module_imports_nothing_impure(name: str) -> None:
    path = ROOT / name if (ROOT / name).exists() else ROOT / "channel" / name
    tree = ast.parse(path.read_text())
    imported = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            imported |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            imported.add(node.module.split(".")[0])
    assert not imported & FORBIDDEN, f"{name} imports {sorted(imported & FORBIDDEN)}"
