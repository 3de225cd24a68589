"""The object-recognition core and the deconvolution stay pure: no transport, files or clocks."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]
FORBIDDEN = {"zenoh", "msgpack", "mcap", "serial", "time", "datetime", "socket", "threading"}
PURE = [
    *sorted((ROOT / "fusion_center" / "objects").glob("*.py")),
    ROOT / "node_agent" / "dsp" / "deconvolution.py",
    ROOT / "sim_nodes" / "circle_scan.py",
    ROOT / "sim_nodes" / "channel" / "prism.py",
]


@pytest.mark.parametrize("path", PURE, ids=lambda p: p.name)
def test_module_imports_nothing_impure(path: Path) -> None:
    imported = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            imported |= {a.name.split(".")[0] for a in node.names}
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            imported.add(node.module.split(".")[0])
    assert not imported & FORBIDDEN, f"{path.name} imports {sorted(imported & FORBIDDEN)}"
    assert "open(" not in path.read_text(), f"{path.name} opens files"
