"""Run Python code in a fresh process where numba has no usable cache directory."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def run_without_numba_cache(
    code: str, tmp_path: Path, timeout: float
) -> subprocess.CompletedProcess[str]:
    """``python -c code`` with this checkout on ``PYTHONPATH`` and numba's only cache locator
    pointing below a regular file: not creatable, even for root (file permissions alone do
    not stop root), so numba refuses ``cache=True``."""
    blocked = tmp_path / "file"
    blocked.write_text("")
    env = {
        **os.environ,
        "PYTHONPATH": str(ROOT),
        "NUMBA_CACHE_LOCATOR_CLASSES": "UserProvidedCacheLocator",
        "NUMBA_CACHE_DIR": str(blocked / "numba"),
    }
    return subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=timeout
    )
