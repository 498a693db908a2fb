"""The S3 endpoint goes away mid-run (the local moto server is stopped): a
real `idda produce` subprocess ends with one `error:` line naming the storage
error and the endpoint (never a secret), how many episodes are done and how
to resume, and exit code 1."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from manifests.reader import done_episodes
from storage import Storage
from tests.s3_server import SECRET_KEY, local_s3_server
from tests.test_produce import ARGS

pytestmark = pytest.mark.slow
REPO = Path(__file__).resolve().parents[1]
DRIVER_DONE = re.compile(r"episodes [1-9]\d*/4")  # a progress line once the driver has an episode done


def test_storage_outage_mid_run_is_one_line_and_exit_1(tmp_path):
    with local_s3_server() as server:
        uri = server.uri("outage")
        cmd = [sys.executable, "-m", "pipeline.cli", "produce", *ARGS, "--out", uri, "--workers", "1", "--max-retries", "1"]
        env = {**{k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"}, "PYTHONPATH": str(REPO)}
        proc = subprocess.Popen(cmd, env=env, start_new_session=True, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        err: list[str] = []
        out: list[str] = []
        readers = [threading.Thread(target=lambda f=f, to=to: to.extend(iter(f.readline, "")), daemon=True)
                   for f, to in ((proc.stderr, err), (proc.stdout, out))]
        for reader in readers:
            reader.start()
        storage = Storage.from_uri(uri)
        deadline = time.time() + 240
        # wait until the run itself has counted a finished episode (its progress line), not only until one is in
        # storage: an episode committed a moment before the outage may not have reached the driver yet, and the
        # error line counts what the driver knows
        while time.time() < deadline and proc.poll() is None and not any(DRIVER_DONE.search(x) for x in err):
            time.sleep(0.2)
        assert proc.poll() is None, f"the run ended before the outage: {''.join(err)[-2000:]}"
        assert len(done_episodes(storage)) >= 1
        server.stop()
        proc.wait(timeout=420)
        for reader in readers:
            reader.join(timeout=30)
        stdout, stderr = "".join(out), "".join(err)
    assert proc.returncode == 1, stderr[-3000:]
    assert "Traceback" not in stderr and SECRET_KEY not in stderr + stdout
    lines = [line for line in stderr.strip().splitlines() if not line.startswith("rendering ")]  # progress lines
    assert len(lines) == 1, stderr
    line = lines[0]
    assert line.startswith("error: ") and server.endpoint in line, line
    done = int(line.split(" of 4 episodes are done")[0].rsplit("; ", 1)[1])
    assert 1 <= done < 4 and "run the same command again to resume" in line
