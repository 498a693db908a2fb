"""Tables of frames built without pa.array (storage.buffers.arrow_column): the same arrays and
Parquet bytes as pa.array/pa.table, the same refusals, and no pandas import in a render worker."""

from __future__ import annotations

import io
import subprocess
import sys

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from storage.buffers import arrow_column

from tests.test_setup import REPO


def _parquet(array: pa.Array) -> bytes:
    sink = io.BytesIO()
    pq.write_table(pa.table({"c": array}), sink, compression="zstd", write_statistics=True, write_page_checksum=True)
    return sink.getvalue()


CASES = [
    (pa.int16(), [1, -2, None, np.int64(7), -2**15, 2**15 - 1]),
    (pa.int32(), [2**31 - 1, -2**31, 2.0, np.int32(3)]),
    (pa.int64(), [2**62, None, None]),
    (pa.float32(), [1.1, None, np.float64(2.5), float("nan"), 3, 1e-45]),
    (pa.float64(), [1e300, None, -0.0, np.float32(0.1)]),
    (pa.string(), ["a", None, "é", ""]),
    (pa.string(), ["", ""]),
    (pa.string(), []),
    (pa.int32(), []),
    (pa.float32(), [None]),
    (pa.list_(pa.float64(), 9), [list(range(9)), None, np.arange(9.0) / 3]),
    (pa.list_(pa.float64(), 16), [None, None]),
    (pa.list_(pa.float64(), 16), [np.eye(4)]),
]


@pytest.mark.parametrize("kind,values", CASES, ids=lambda c: str(c)[:30])
def test_a_column_is_the_array_pa_array_gives(kind, values):
    mine, theirs = arrow_column(values, kind), pa.array(values, type=kind)
    mine.validate(full=True)
    assert mine.type == theirs.type and mine.null_count == theirs.null_count
    assert mine.to_pylist() == theirs.to_pylist() or (mine.is_nan().to_pylist() == theirs.is_nan().to_pylist())
    assert _parquet(mine) == _parquet(theirs)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.one_of(st.none(), st.integers(-2**31, 2**31 - 1)), max_size=40),
       st.lists(st.one_of(st.none(), st.floats(width=32)), max_size=40),
       st.lists(st.one_of(st.none(), st.text(max_size=6)), max_size=40))
def test_any_values_give_the_same_parquet_bytes(ints, floats, texts):
    for kind, values in ((pa.int32(), ints), (pa.float32(), floats), (pa.string(), texts)):
        assert _parquet(arrow_column(values, kind)) == _parquet(pa.array(values, type=kind))


@pytest.mark.parametrize("kind,values", [
    (pa.int16(), [40000]),  # out of range, as pa.array refuses
    (pa.string(), [5]),  # not a string
    (pa.list_(pa.float64(), 9), [[1.0, 2.0]]),  # the wrong length
    (pa.int32(), [True]),  # a bool is not a number here
    (pa.float32(), ["x"]),
    (pa.int32(), [2.5]),  # pa.array truncates this one; a frame's integer never has a fraction
    (pa.bool_(), [True]),  # no builder: said, not guessed
])
def test_values_that_do_not_fit_raise_value_error(kind, values):
    with pytest.raises(ValueError):
        arrow_column(values, kind)


def test_a_part_with_a_value_that_does_not_fit_is_a_manifest_error():
    from manifests.part_file import ManifestError
    from manifests.synthetic import episode_rows
    from manifests.writer import part_table
    from pipeline.planner import make_plan
    from pipeline.settings import PlanConfig

    rows = episode_rows(make_plan(PlanConfig(domains="T01_CN_A", frames_per_scenario=2)).episodes[0])
    table = part_table(rows)
    assert table.equals(pa.table({k: [r[k] for r in rows] for k in table.schema.names}, schema=table.schema))
    rows[1]["episode"] = "one"
    with pytest.raises(ManifestError, match="episode"):
        part_table(rows)


NO_PANDAS = """
import pickle, sys
from manifests.writer import part_bytes, part_table
from outputs.objects import OBJECT_SCHEMA, object_table, write_objects

rows = pickle.loads(sys.stdin.buffer.read())
part_bytes(part_table(rows))
row = {f.name: ("vehicle" if f.type == "string" else 1) for f in OBJECT_SCHEMA}
write_objects(object_table([row, row]))
print("pandas" in sys.modules)
"""


def test_a_worker_writes_its_tables_without_importing_pandas():
    """pa.array and pa.table import pandas (~0.25 CPU-s) to check their input; a render worker
    writes an objects table per frame and a part per episode and needs nothing else of it."""
    import pickle

    from manifests.synthetic import episode_rows
    from pipeline.planner import make_plan
    from pipeline.settings import PlanConfig

    rows = episode_rows(make_plan(PlanConfig(domains="T01_CN_A", frames_per_scenario=3)).episodes[0])
    done = subprocess.run([sys.executable, "-c", NO_PANDAS], cwd=REPO, input=pickle.dumps(rows), capture_output=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr.decode()
    assert done.stdout.decode().strip() == "False"
