"""Test-session settings: built worlds are cached in a temp dir, never in the user's ~/.cache."""

from __future__ import annotations

import os
import shutil
import tempfile

_CACHE: str | None = None


def pytest_configure(config):
    global _CACHE
    if "IDDA_WORLD_CACHE" not in os.environ:  # set before any test starts Ray: workers inherit it
        _CACHE = tempfile.mkdtemp(prefix="idda-world-cache-")
        os.environ["IDDA_WORLD_CACHE"] = _CACHE


def pytest_unconfigure(config):
    if _CACHE is not None:
        shutil.rmtree(_CACHE, ignore_errors=True)
