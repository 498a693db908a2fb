"""A draw cut short never changes what the renderer draws next.

Ray's cancel raises KeyboardInterrupt in a running task's thread (the driver cancels, not forced, the
episodes it has not heard from when a node is lost), so a worker's renderer can be stopped in the middle
of a GL pass and then render the next episode. CI once saw every HRN episode of such a run differ from a
local run's: a shadow pass cut short had left polygon offset on, and HRN, which draws no shadows, drew
every later episode's depth (and with it classes, instances and objects) shifted."""

from __future__ import annotations

import numpy as np
import pytest

from pipeline.planner import make_plan
from pipeline.settings import PlanConfig
from render_workers.render import passes
from render_workers.render.episode import render_episode
from render_workers.render.renderer import Renderer

# CN draws sun shadows, HRN (overcast) none: the episode after a cut-short CN is an HRN one
PLAN = PlanConfig(domains="towns=T01 weathers=CN,HRN viewpoints=A", frames_per_scenario=1, width=64, height=36, seed=3)
BUFFERS = ("rgb", "depth", "classes", "instance")


def _specs():
    by_weather = {spec.scenario.split("_")[1]: spec.drawing for spec in make_plan(PLAN).episodes}
    return by_weather["CN"], by_weather["HRN"]


def _frames(spec, renderer) -> list[dict]:
    frames = []
    render_episode(spec, frames.append, world="test", renderer=renderer)
    return [{name: np.array(frame.buffers[name]) for name in BUFFERS} for frame in frames]


@pytest.fixture(scope="module")
def fresh_hrn():
    """The HRN episode as a new renderer draws it."""
    with Renderer() as r:
        return _frames(_specs()[1], r)


def _assert_same(got: list[dict], want: list[dict]) -> None:
    assert len(got) == len(want)
    for index, (a, b) in enumerate(zip(got, want)):
        for name in BUFFERS:
            assert np.array_equal(a[name], b[name]), f"frame {index}: {name} differs from a new renderer's"


def _cut_short_once(monkeypatch, module, name: str) -> list:
    """``module.name`` raises KeyboardInterrupt at its first call (as Ray's cancel would), then is itself."""
    original, calls = getattr(module, name), []

    def interrupted(*args, **kwargs):
        calls.append(name)
        if len(calls) == 1:
            raise KeyboardInterrupt
        return original(*args, **kwargs)

    monkeypatch.setattr(module, name, interrupted)
    return calls


@pytest.mark.parametrize("where", ["shadow pass", "read-back", "scene build"])
def test_the_episode_after_a_draw_cut_short_is_drawn_as_by_a_new_renderer(fresh_hrn, monkeypatch, where):
    """Cut short, a renderer's next load makes a new GL context (its state and the renderer's caches are
    not to be trusted) and draws what a new renderer draws; episodes that ran through keep the context."""
    cn, hrn = _specs()
    with Renderer() as r:
        _frames(cn, r)  # a worker that has drawn an episode already
        context = r._offscreen
        _frames(cn, r)
        assert r._offscreen is context, "an episode that ran through made a new context"
        if where == "shadow pass":  # a shadow caster's draw call (the pass sets polygon offset first)
            calls = _cut_short_once(monkeypatch, passes, "draw_primitive")
        elif where == "read-back":  # the first frame's colour pass (labels and depth in it), drawn and not yet read
            calls = _cut_short_once(monkeypatch, passes, "_read_merged")
        else:
            calls = _cut_short_once(monkeypatch, Renderer, "_build_actors")
        with pytest.raises(KeyboardInterrupt):
            _frames(cn, r)
        assert calls, "the draw was not cut short where the test meant it to be"
        monkeypatch.undo()
        _assert_same(_frames(hrn, r), fresh_hrn)
        assert r._offscreen is not context and r._offscreen is not None


def test_a_forward_pass_draws_the_same_whatever_polygon_offset_it_finds():
    """A pass sets the depth state it draws with: polygon offset left on by whatever ran before
    (here set by hand) does not shift its depth."""
    from OpenGL import GL

    _, hrn = _specs()
    with Renderer() as r:
        want = _frames(hrn, r)
        GL.glEnable(GL.GL_POLYGON_OFFSET_FILL)  # the renderer's context is current in this thread
        GL.glPolygonOffset(*passes.SHADOW_POLYGON_OFFSET)
        _assert_same(_frames(hrn, r), want)
