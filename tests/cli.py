"""Running ``uwbnet`` as a user does, for the command-line tests: a real process."""

from __future__ import annotations

import json
import subprocess
import sys
from typing import Any


def uwbnet(*args: str, timeout: float = 240.0) -> subprocess.CompletedProcess[str]:
    """Run ``uwbnet ARGS`` in a child interpreter; its exit status, stdout and stderr."""
    return subprocess.run(
        [sys.executable, "-m", "uwbnet.cli", *args],
        capture_output=True,
        text=True,
        timeout=timeout,
        check=False,
    )


def last_json(proc: subprocess.CompletedProcess[str]) -> Any:
    """The JSON object on the last line of a command's stdout."""
    return json.loads(proc.stdout.strip().splitlines()[-1])


def assert_one_line_error(proc: subprocess.CompletedProcess[str], *fragments: str) -> None:
    """A failed command: non-zero exit, one stderr line with every fragment, no traceback."""
    assert proc.returncode != 0
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert "Traceback" not in proc.stderr
    for f in fragments:
        assert f in lines[0], lines[0]
