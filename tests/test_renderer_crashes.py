"""Render workers that die of a native fault (Mesa's llvmpipe aborts with
LP_NATIVE_VECTOR_WIDTH=128 on our shaders: "double free or corruption") stop
the run with one line naming the GL settings in force, instead of "N
episode(s) failed; run the same command again"; one crash among finished
episodes stays an ordinary failed episode."""

from __future__ import annotations

import os

import pytest

from benchmarks.bench_control import standin_episode
from pipeline.driver import CRASHES_TO_STOP, RendererCrashes, gl_settings, produce
from pipeline.settings import PlanConfig, ProduceConfig, RunConfig

PLAN = PlanConfig(domains="towns=T01,T02 weathers=CN viewpoints=A,B", frames_per_scenario=2, width=64, height=36)


def aborting_episode(spec, storage, world="test", on_frame=None, fence=None):
    """A worker whose renderer aborts the process, as llvmpipe does."""
    os.abort()


def aborting_after_the_first(spec, storage, world="test", on_frame=None, fence=None):
    if (spec.scenario, spec.episode) != ("T01_CN_A", 0):
        os.abort()
    return standin_episode(spec, storage, world=world, on_frame=on_frame, fence=fence)


def _config(tmp_path) -> ProduceConfig:
    # one worker, one task in flight: the episodes run in plan order
    return ProduceConfig(run=RunConfig(PLAN, world="test"), out=str(tmp_path / "out"), workers=1, max_retries=0,
                         max_in_flight=1)


def test_gl_settings_name_the_drivers_variables_not_the_default_platform():
    env = {"LP_NATIVE_VECTOR_WIDTH": "128", "MESA_GL_VERSION_OVERRIDE": "3.3", "PYOPENGL_PLATFORM": "egl",
           "HOME": "/root", "GALLIUM_DRIVER": "llvmpipe"}
    assert gl_settings(env) == ["GALLIUM_DRIVER=llvmpipe", "LP_NATIVE_VECTOR_WIDTH=128", "MESA_GL_VERSION_OVERRIDE=3.3"]
    assert gl_settings({"PYOPENGL_PLATFORM": "osmesa"}) == ["PYOPENGL_PLATFORM=osmesa"]


@pytest.mark.slow
def test_workers_that_always_crash_stop_the_run_in_one_line(tmp_path, monkeypatch):
    import ray

    if ray.is_initialized():
        ray.shutdown()
    monkeypatch.setenv("MESA_SHADER_CACHE_DISABLE", "true")  # harmless here: the stand-in draws nothing
    with pytest.raises(RendererCrashes) as stop:
        produce(_config(tmp_path), episode_fn=aborting_episode)
    report = stop.value.report
    assert stop.value.crashed == CRASHES_TO_STOP < 4 and report.rendered_episodes == 0
    message = str(stop.value)
    assert "\n" not in message and "retrying cannot help" in message
    assert "MESA_SHADER_CACHE_DISABLE=true" in message


@pytest.mark.slow
def test_a_crash_after_a_finished_episode_is_one_failed_episode(tmp_path):
    import ray

    if ray.is_initialized():
        ray.shutdown()
    report = produce(_config(tmp_path), episode_fn=aborting_after_the_first)
    assert report.rendered_episodes == 1 and report.crashed == 3 and len(report.failed) == 3
