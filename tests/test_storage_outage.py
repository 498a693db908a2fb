"""The S3 endpoint goes away mid-run (the local moto server is stopped): a
real `idda produce` subprocess ends with one `error:` line naming the storage
error and the endpoint (never a secret), how many episodes are done and how
to resume, and exit code 1."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from pathlib import Path

import pytest

from manifests.reader import done_episodes
from storage import Storage
from tests.s3_server import SECRET_KEY, local_s3_server
from tests.test_produce import ARGS

pytestmark = pytest.mark.slow
REPO = Path(__file__).resolve().parents[1]


def test_storage_outage_mid_run_is_one_line_and_exit_1(tmp_path):
    with local_s3_server() as server:
        uri = server.uri("outage")
        cmd = [sys.executable, "-m", "pipeline.cli", "produce", *ARGS, "--out", uri, "--workers", "1", "--max-retries", "1"]
        env = {**{k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"}, "PYTHONPATH": str(REPO)}
        proc = subprocess.Popen(cmd, env=env, start_new_session=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        storage = Storage.from_uri(uri)
        deadline = time.time() + 240
        while time.time() < deadline and proc.poll() is None and len(done_episodes(storage)) < 1:
            time.sleep(0.2)
        assert proc.poll() is None, f"the run ended before the outage: {proc.stderr.read()[-2000:]}"
        server.stop()
        stdout, stderr = proc.communicate(timeout=420)
    assert proc.returncode == 1, stderr[-3000:]
    assert "Traceback" not in stderr and SECRET_KEY not in stderr + stdout
    lines = [line for line in stderr.strip().splitlines() if not line.startswith("rendering ")]  # progress lines
    assert len(lines) == 1, stderr
    line = lines[0]
    assert line.startswith("error: ") and server.endpoint in line, line
    done = int(line.split(" of 4 episodes are done")[0].rsplit("; ", 1)[1])
    assert 1 <= done < 4 and "run the same command again to resume" in line
