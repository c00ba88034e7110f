"""Fixtures of the integration tests: the headless Chromium of the viewer's browser tests."""

from __future__ import annotations

import os

import pytest

CHROMIUM = "/usr/bin/chromium"
CHROMIUM_ARGS = [
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--no-first-run",
]


@pytest.fixture(scope="module")
def browser(request):
    """A headless Chromium (playwright) for a module's tests: they skip where it is not installed
    or cannot start. A module's ``CHROMIUM_EXTRA_ARGS`` are added to its command line."""
    if not os.path.exists(CHROMIUM):
        pytest.skip(f"chromium is not installed at {CHROMIUM}")
    sync_api = pytest.importorskip("playwright.sync_api")
    with sync_api.sync_playwright() as p:
        try:
            b = p.chromium.launch(executable_path=CHROMIUM, args=CHROMIUM_ARGS + getattr(request.module, "CHROMIUM_EXTRA_ARGS", []))
        except Exception as exc:  # noqa: BLE001 - a broken browser install is a skip, not a failure
            pytest.skip(f"cannot launch chromium: {exc}")
        yield b
        b.close()
