"""Debian's headless Chromium under Playwright, for the browser tests.

Uses the system browser (``/usr/bin/chromium``, or ``UWBNET_CHROMIUM``), never a downloaded
one, with a fresh profile in the test's tmp dir. Tests skip, with the reason printed by
pytest's ``-ra`` summary, when Chromium or Playwright is missing.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

CHROMIUM = os.environ.get("UWBNET_CHROMIUM", "/usr/bin/chromium")

#: Headless, and nothing that reaches out to the network (the machine's network is closed).
FLAGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-quic",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
]


@contextlib.contextmanager
def browser_page(tmp_path: Path, viewport: tuple[int, int] = (1400, 800)) -> Iterator[Any]:
    """A Playwright page in headless Chromium with a fresh ``--user-data-dir``."""
    if not Path(CHROMIUM).exists():
        pytest.skip(f"no Chromium at {CHROMIUM} (apt-get install chromium)")
    try:
        from playwright.sync_api import sync_playwright
    except ImportError:
        pytest.skip("playwright is not installed (pip install -e '.[test]')")
    profile = tmp_path / "chromium-profile"
    with sync_playwright() as pw:
        context = pw.chromium.launch_persistent_context(
            str(profile),
            executable_path=CHROMIUM,
            headless=True,
            args=FLAGS,
            viewport={"width": viewport[0], "height": viewport[1]},
        )
        try:
            page = context.pages[0] if context.pages else context.new_page()
            page.set_default_timeout(20_000)
            yield page
        finally:
            context.close()
