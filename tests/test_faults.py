"""Fault injection: truncate, flip and delete each kind of file in a finished
root (a frame, a manifest part, an index, run.json), then verify, repair,
verify; the root must end byte-identical to a clean run. Real Ray, real files."""

from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

import pyarrow.compute as pc
import pytest

from outputs.table import DEFAULT_OUTPUTS as OUTPUTS
from manifests.reader import read_manifest
from manifests.schema import index_path, part_path
from roots.verify import verify
from pipeline.driver import produce
from tests.roots import part_of
from tests.test_produce import config, ray_local  # noqa: F401 (fixtures)

pytestmark = pytest.mark.slow

# One file of each kind (relative paths in the small run of tests.test_produce).
KINDS = {
    "frame": lambda table: table.column("semantic_raw_path")[5].as_py(),
    "part": lambda table: part_path("T07_CN_A", 0, table.filter(pc.and_(pc.equal(table.column("scenario"), "T07_CN_A"),
                                                                      pc.equal(table.column("episode"), 0))).num_rows),
    "index": lambda table: index_path("T01_HRN_A"),
    "run.json": lambda table: "run.json",
}


def _truncate(path: Path) -> None:
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 3])


def _flip(path: Path) -> None:
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0x5A
    path.write_bytes(bytes(data))


def _delete(path: Path) -> None:
    path.unlink()


FAULTS = {"truncate": _truncate, "flip": _flip, "delete": _delete}
# What verify must report before the repair: a deleted index is no damage
# (indexes are derived; readers use the parts and the next run rebuilds it).
EXPECTED = {
    ("frame", "truncate"): "corrupt", ("frame", "flip"): "corrupt", ("frame", "delete"): "missing",
    ("part", "truncate"): "bad-part", ("part", "flip"): "bad-part", ("part", "delete"): "extra",
    ("index", "truncate"): "bad-index", ("index", "flip"): "bad-index", ("index", "delete"): None,
    ("run.json", "truncate"): "bad-run", ("run.json", "flip"): "bad-run", ("run.json", "delete"): "bad-run",
}


@pytest.fixture
def clean(reference) -> Path:
    """The session's clean render of the plan (conftest's ``reference``)."""
    return reference


def whole_tree(root: Path) -> dict[str, str]:
    """sha256 of every file under root but worker timings and leases (run.json and indexes included)."""
    return {
        p.relative_to(root).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
        for p in sorted(root.rglob("*"))
        if p.is_file() and not p.relative_to(root).as_posix().startswith(("_stats/", "_lease/"))
    }


@pytest.mark.parametrize("fault", list(FAULTS))
@pytest.mark.parametrize("kind", list(KINDS))
def test_fault_is_found_and_repaired_to_a_clean_root(ray_local, clean, tmp_path, kind, fault):
    root = tmp_path / "root"
    shutil.copytree(clean, root)
    rel = KINDS[kind](read_manifest(str(clean)))
    FAULTS[fault](root / rel)

    before = verify(str(root))
    expected = EXPECTED[(kind, fault)]
    if expected is None:
        assert before.ok
    else:
        assert not before.ok and expected in before.counts(), before.problems
        assert any(p.path == rel or p.kind == "extra" for p in before.problems)

    report = produce(config(root, repair=True))
    assert report.ok

    after = verify(str(root))
    assert after.ok, after.problems
    assert whole_tree(root) == whole_tree(clean)


def test_s3_damaged_part_and_index_are_repaired(clean):
    """The same on an s3:// root (moto): a flipped part and a truncated index."""
    import ray

    from storage import Storage
    from tests.s3_server import local_s3_server

    if ray.is_initialized():
        ray.shutdown()  # produce starts its own cluster, which inherits the S3 settings
    with local_s3_server() as server:
        uri = server.uri("faults")
        storage = Storage.from_uri(uri)
        for path in sorted(clean.rglob("*")):
            if path.is_file():
                storage.write_bytes(path.relative_to(clean).as_posix(), path.read_bytes())
        part, index = part_of(storage, "T07_CN_A", 0), index_path("T01_HRN_A")
        data = bytearray(storage.read_bytes(part))
        data[len(data) // 2] ^= 0x5A
        storage.write_bytes(part, bytes(data))
        storage.write_bytes(index, storage.read_bytes(index)[:100])
        assert verify(storage).counts() == {"bad-part": 1, "bad-index": 1, "extra": 4 * len(OUTPUTS)}  # the damaged part's 4 frames
        assert produce(config(uri, repair=True)).rendered_episodes == 1
        assert verify(storage).ok
        for rel, digest in whole_tree(clean).items():
            assert storage.sha256(rel) == digest, rel
