"""A real `idda produce` subprocess stopped the way batch schedulers and closed
terminals stop it (SIGTERM, SIGHUP) mid-run: one line that says how to
resume, exit 128 + the signal, no traceback, no lease left behind, nothing of
its Ray cluster still running; a rerun completes to the reference bytes.
Ray's processes are found by the run's own Ray temp dir (RAY_TMPDIR), never by name."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

from manifests.reader import done_episodes
from pipeline.planner import make_plan
from storage import Storage
from tests.test_produce import ARGS, PLAN, ray_local, tree_digest  # noqa: F401 (fixtures)

pytestmark = pytest.mark.slow
REPO = Path(__file__).resolve().parents[1]


def processes_using(marker: str) -> list[int]:
    """Live processes whose command line or environment mentions ``marker``."""
    found = []
    for entry in os.listdir("/proc"):
        if not entry.isdigit() or int(entry) == os.getpid():
            continue
        for part in ("cmdline", "environ"):
            try:
                with open(f"/proc/{entry}/{part}", "rb") as f:
                    if marker.encode() in f.read():
                        found.append(int(entry))
                        break
            except OSError:
                continue
    return found


@pytest.fixture
def ray_tmpdir():
    """A Ray temp dir of this test alone (short: Unix socket paths live under it)."""
    path = tempfile.mkdtemp(prefix="rt", dir="/tmp")
    yield path
    shutil.rmtree(path, ignore_errors=True)


def _cmd(out: Path) -> list[str]:
    return [sys.executable, "-m", "pipeline.cli", "produce", *ARGS, "--out", str(out), "--workers", "1"]


def _env(ray_tmpdir: str) -> dict:
    env = {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"}
    return {**env, "PYTHONPATH": str(REPO), "RAY_TMPDIR": ray_tmpdir}


@pytest.mark.parametrize("sig, code", [(signal.SIGTERM, 143), (signal.SIGHUP, 129)], ids=["SIGTERM", "SIGHUP"])
def test_signal_stops_like_ctrl_c(reference, tmp_path, ray_tmpdir, sig, code):
    out = tmp_path / "signalled"
    proc = subprocess.Popen(_cmd(out), env=_env(ray_tmpdir), start_new_session=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    storage = Storage.from_uri(str(out))
    deadline = time.time() + 240
    while time.time() < deadline and proc.poll() is None:
        if (out / "run.json").exists() and len(done_episodes(storage)) >= 1:
            break
        time.sleep(0.2)
    assert proc.poll() is None, f"the run ended before it could be signalled: {proc.stderr.read()[-2000:]}"
    proc.send_signal(sig)  # the driver alone, as `kill` or a scheduler sends it
    _, stderr = proc.communicate(timeout=120)
    assert proc.returncode == code, stderr[-3000:]
    assert "Traceback" not in stderr and "Error" not in stderr, stderr[-3000:]
    lines = [line for line in stderr.strip().splitlines() if not line.startswith("rendering ")]  # progress lines
    assert len(lines) == 1, stderr
    assert lines[0].startswith(f"stopped by {signal.Signals(sig).name}: ") and "run the same command again to resume" in lines[0]
    assert not list(out.glob("_lease/producer-*")), "the producer's lease was left behind"
    assert processes_using(ray_tmpdir) == [], "processes of the run's Ray cluster outlived it"
    done = len(done_episodes(storage))
    assert 1 <= done < len(make_plan(PLAN).episodes)
    if sig != signal.SIGTERM:  # both stop through the same handler; one rerun shows that what a stop leaves resumes
        return
    result = subprocess.run(_cmd(out), env=_env(ray_tmpdir), capture_output=True, text=True, timeout=600)
    assert result.returncode == 0, result.stderr[-3000:]
    assert f"{done} of 4 episodes were already done" in result.stdout
    assert tree_digest(out) == tree_digest(reference)
    assert processes_using(ray_tmpdir) == [], "processes of the run's Ray cluster outlived it"


def test_the_driver_reads_a_result_without_importing_the_renderer():
    """The driver unpickles each episode's result inside ray.get, where Ray turns a KeyboardInterrupt into a
    failed result: a SIGTERM that arrived while the result's module was being imported (the renderer, the
    first time) was lost, and the run went on to the end. The result's class lives where the driver has it
    already, so reading one imports nothing."""
    import pickle

    from pipeline.episode_job import EpisodeResult

    data = pickle.dumps(EpisodeResult("T01_CN_A", 0, 4, 1.0, "node", 1))
    probe = ("import pickle, sys; import pipeline.driver; before = set(sys.modules); "
             "pickle.loads(sys.stdin.buffer.read()); print(sorted(set(sys.modules) - before))")
    done = subprocess.run([sys.executable, "-c", probe], input=data, capture_output=True, cwd=REPO,
                          env={**os.environ, "PYTHONPATH": str(REPO)}, timeout=120)
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.decode().strip() == "[]", done.stdout.decode()[-2000:]
