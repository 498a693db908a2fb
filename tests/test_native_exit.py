"""No native crash at exit (issue 33: ``idda verify`` on a root whose run.json
pairing flag was flipped was refused correctly, but exited 134, "terminate
called without an active exception", in 2 of 31 runs).

The cause (a backtrace under gdb): manifest bytes already in memory were
handed to pyarrow as Python objects (``io.BytesIO``, then ``pa.BufferReader``
over Python bytes). A scan may drop the last reference to its fragment, and so
to that Python object, in one of Arrow's own threads, which then takes the GIL
(``arrow::py::PyBuffer::~PyBuffer`` -> ``PyGILState_Ensure``). While the
interpreter finalizes, such a thread is made to exit (``pthread_exit``) and the
forced unwind through Arrow's C++ frames ends in ``std::terminate``. Bytes in
memory now go to Arrow as a copy it owns (``storage.buffers.arrow_reader``):
no Arrow thread ever touches a Python object.
"""

from __future__ import annotations

import json
import subprocess
import sys

import pyarrow as pa
import pytest

from roots.run_file import record_bytes
from tests.faultkit import REPO
from tests.test_control_plane import MANY, synthetic_root


def _flipped_pairing(tmp_path):
    root = tmp_path / "root"
    synthetic_root(str(root), MANY)
    record = json.loads((root / "run.json").read_text())
    record.pop("checksum")
    record["config"]["pairing"] = 1 - record["config"].get("pairing", 0)
    (root / "run.json").write_bytes(record_bytes(record))
    return root


@pytest.mark.slow
def test_verify_refuses_a_flipped_pairing_flag_without_a_native_crash(tmp_path):
    """10 runs of ``idda verify``, two at a time: each exits 1 (the parts' seeds do not
    derive from run.json), none aborts (134) or prints "terminate called"."""
    root = _flipped_pairing(tmp_path)
    command = [sys.executable, "-m", "pipeline.cli", "verify", str(root), "--no-ray"]
    codes = []
    for _ in range(5):
        runs = [subprocess.Popen(command, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
                for _ in range(2)]
        for run in runs:
            out, err = run.communicate(timeout=120)
            assert "terminate called" not in err and "Fatal Python error" not in err, err[-2000:]
            assert "seed does not derive from run.json" in out, out[-2000:]
            codes.append(run.returncode)
    assert codes == [1] * 10


def test_arrow_reads_hold_no_python_object():
    """What manifest reads give pyarrow owns its memory: ``pa.BufferReader(data)`` keeps
    ``data`` alive from Arrow's side (the reference a worker thread dropped at exit)."""
    from storage.buffers import arrow_reader

    data = b"PAR1" * 1000
    before = sys.getrefcount(data)
    reader = arrow_reader(data)
    assert sys.getrefcount(data) == before and reader.read() == data
    held = pa.BufferReader(data)  # what the reads used: a reference from Arrow's side
    assert sys.getrefcount(data) == before + 1 and held.read() == data
