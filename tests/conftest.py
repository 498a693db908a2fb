"""Test-session settings: built worlds are cached in a temp dir, never in the user's ~/.cache."""

from __future__ import annotations

import os
import shutil
import tempfile

import pytest

_CACHE: str | None = None


def pytest_configure(config):
    global _CACHE
    if "IDDA_WORLD_CACHE" not in os.environ:  # set before any test starts Ray: workers inherit it
        _CACHE = tempfile.mkdtemp(prefix="idda-world-cache-")
        os.environ["IDDA_WORLD_CACHE"] = _CACHE


def pytest_unconfigure(config):
    if _CACHE is not None:
        shutil.rmtree(_CACHE, ignore_errors=True)


@pytest.fixture(scope="session")
def reference(tmp_path_factory):
    """The plan of ``tests.test_produce`` (PLAN) rendered once per session, without
    Ray, indexes included: what every produce, resume and repair of it must equal,
    byte for byte. Read-only: tests copy it before they change anything."""
    from pipeline.settings import RunConfig
    from tests.roots import render_root
    from tests.test_produce import PLAN

    root = tmp_path_factory.mktemp("reference") / "root"
    render_root(root, RunConfig(plan=PLAN, world="test"), compact=True)
    return root


class _ProceduralWorlds(dict):
    """Town code -> the procedural world of seed 0, built on first use (or loaded from the
    session's world cache, which the other pytest workers and the render workers share)."""

    def __missing__(self, code: str):
        from render_workers.worlds import world, worldcache

        self[code] = built = worldcache.load_or_build("procedural", code, 0, world.build_world)
        return built


@pytest.fixture(scope="session")
def procedural_worlds():
    """The seven towns' worlds (seed 0), each built once per test session: a town takes
    seconds to build, and the world and town-look tests read the same ones. Read-only."""
    return _ProceduralWorlds()
