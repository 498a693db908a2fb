"""storage/: URIs, atomic writes, checksums, errors; local and against a local S3 server."""

from __future__ import annotations

import errno
import hashlib
import os
import pickle
import threading
import uuid

import pyarrow as pa
import pyarrow.dataset as ds
import pyarrow.fs as pafs
import pyarrow.parquet as pq
import pytest
from hypothesis import given
from hypothesis import strategies as st

import storage.fs as storage_fs
from storage import Storage, StorageError, sha256_bytes
from storage.errors import redact
from storage.uri import clean_rel
from tests.s3_server import SECRET_KEY, s3_server  # noqa: F401  (fixture)

MIB = 1 << 20


@pytest.fixture(params=["local", "s3"])
def store(request, tmp_path) -> Storage:
    """An empty Storage on a local directory and on the local S3 server."""
    if request.param == "local":
        return Storage.from_uri(str(tmp_path / "out"))
    server = request.getfixturevalue("s3_server")
    return Storage.from_uri(server.uri(f"run-{uuid.uuid4().hex[:12]}"))


def _all_local_files(root) -> list[str]:
    return sorted(
        os.path.relpath(os.path.join(d, f), root) for d, _, files in os.walk(root) for f in files
    )


def _raw_keys(store: Storage) -> list[str]:
    """Every object under the root, temp keys included (bypasses list_files' filtering)."""
    selector = pafs.FileSelector(store.path(), recursive=True, allow_not_found=True)
    infos = store.filesystem.get_file_info(selector)
    return sorted(i.path for i in infos if i.type == pafs.FileType.File)


# -- both backends -----------------------------------------------------------------


def test_round_trip(store):
    store.write_bytes("a/b/c.bin", b"hello")
    assert store.read_bytes("a/b/c.bin") == b"hello"
    assert store.exists("a/b/c.bin") and not store.exists("a/b/missing.bin")
    assert not store.exists("a/b")  # directories are not files
    assert store.size("a/b/c.bin") == 5
    store.write_bytes("a/b/c.bin", bytearray(b"replaced"))  # overwrite, bytes-like
    assert store.read_bytes("a/b/c.bin") == b"replaced"
    store.write_bytes("empty", b"")
    assert store.read_bytes("empty") == b"" and store.size("empty") == 0


def test_missing_file_raises_file_not_found(store):
    with pytest.raises(FileNotFoundError, match="nope.bin"):
        store.read_bytes("nope.bin")
    with pytest.raises(FileNotFoundError):
        store.size("nope.bin")
    with pytest.raises(FileNotFoundError):
        store.sha256("nope.bin")


def test_list_sha256_delete(store):
    assert store.list_files() == []  # root not created yet
    for rel in ["b/2.png", "a/1.png", "a/sub/3.parquet", "ab.txt"]:
        store.write_bytes(rel, rel.encode())
    assert store.list_files() == ["a/1.png", "a/sub/3.parquet", "ab.txt", "b/2.png"]
    assert store.list_files("a/") == ["a/1.png", "a/sub/3.parquet"]
    assert store.list_files("a") == ["a/1.png", "a/sub/3.parquet", "ab.txt"]  # string prefix
    assert store.list_files(suffix=".png") == ["a/1.png", "b/2.png"]
    assert store.list_files("a/sub/", suffix=".parquet") == ["a/sub/3.parquet"]
    assert store.list_files("zzz/") == []

    data = os.urandom(2 * MIB + 123)  # more than one 1 MiB chunk
    store.write_bytes("big.bin", data)
    assert store.sha256("big.bin") == hashlib.sha256(data).hexdigest() == sha256_bytes(data)
    assert Storage.sha256_bytes(b"") == hashlib.sha256(b"").hexdigest()

    store.delete("a/1.png")
    store.delete("a/1.png")  # missing is fine
    store.delete("never/existed")
    assert not store.exists("a/1.png")
    assert "a/1.png" not in store.list_files()


def test_create_exclusive(store):
    assert store.create_exclusive("locks/ep1", b"first") is True
    assert store.create_exclusive("locks/ep1", b"second") is False
    assert store.read_bytes("locks/ep1") == b"first"
    assert store.list_files() == ["locks/ep1"]


def test_ensure_writable_leaves_nothing(store):
    store.ensure_writable()
    assert store.list_files() == []
    assert _raw_keys(store) == []


def test_pickle_round_trip(store):
    store.write_bytes("x.bin", b"payload")
    _ = store.filesystem  # a live filesystem must not be pickled
    clone = pickle.loads(pickle.dumps(store))
    assert clone == store and repr(clone) == repr(store)
    assert clone.read_bytes("x.bin") == b"payload"


def test_parquet_through_filesystem_and_path(store):
    table = pa.table({"town": ["T01", "T01", "T07"], "frame": [0, 1, 2]})
    ds.write_dataset(
        table,
        store.path("manifest"),
        filesystem=store.filesystem,
        format="parquet",
        partitioning=["town"],
        partitioning_flavor="hive",
        existing_data_behavior="overwrite_or_ignore",
    )
    assert store.list_files("manifest/", suffix=".parquet")
    got = ds.dataset(
        store.path("manifest"), filesystem=store.filesystem, format="parquet", partitioning="hive"
    ).to_table()
    assert sorted(got.column("frame").to_pylist()) == [0, 1, 2]
    assert sorted(got.column("town").to_pylist()) == ["T01", "T01", "T07"]


def test_parquet_written_with_write_bytes_is_readable(store):
    sink = pa.BufferOutputStream()
    pq.write_table(pa.table({"x": [1, 2, 3]}), sink)
    store.write_bytes("parts/p0.parquet", sink.getvalue().to_pybytes())
    got = ds.dataset(store.path("parts"), filesystem=store.filesystem, format="parquet").to_table()
    assert got.column("x").to_pylist() == [1, 2, 3]


@pytest.mark.parametrize("rel", ["/abs/x", "../x", "a/../../x", "a/..", "", ".", "a\x00b"])
def test_bad_relative_paths(store, rel):
    for call in (store.write_bytes, store.create_exclusive):
        with pytest.raises(ValueError):
            call(rel, b"x")
    for call in (store.read_bytes, store.exists, store.size, store.sha256, store.delete):
        with pytest.raises(ValueError):
            call(rel)
    if rel not in ("", "."):
        with pytest.raises(ValueError):
            store.path(rel)
        with pytest.raises(ValueError):
            store.list_files(rel)


@given(st.text(alphabet="ab./\\\x00", max_size=12))
def test_clean_rel_never_escapes_the_root(rel):
    try:
        clean = clean_rel(rel)
    except ValueError:
        return
    parts = clean.split("/")
    assert clean and not clean.startswith("/") and ".." not in parts and "" not in parts
    assert os.path.normpath(os.path.join("/root", clean)).startswith("/root/")


def test_paths_are_normalised(store):
    assert store.path("a//b/./c") == store.path("a/b/c") == f"{store.path()}/a/b/c"
    assert store.join("a/b").endswith("/a/b")
    with pytest.raises(TypeError):
        store.write_bytes("s.txt", "not bytes")


# -- local only -----------------------------------------------------------------------


def test_local_roots(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    rel_root = Storage.from_uri("out/run")
    assert rel_root.uri == str(tmp_path / "out" / "run")
    assert not (tmp_path / "out").exists()  # created on demand, not by from_uri
    rel_root.write_bytes("f.txt", b"1")
    assert (tmp_path / "out" / "run" / "f.txt").read_bytes() == b"1"
    assert Storage.from_uri(f"file://{tmp_path}/out/run") == rel_root
    assert rel_root.join("f.txt") == str(tmp_path / "out" / "run" / "f.txt")
    assert isinstance(rel_root.filesystem, pafs.LocalFileSystem)


def test_local_writes_leave_no_temp_files(tmp_path):
    store = Storage.from_uri(str(tmp_path))
    for i in range(5):
        store.write_bytes(f"d/{i}.bin", os.urandom(1000))
        store.create_exclusive(f"d/{i}.lock", b"")
        store.create_exclusive(f"d/{i}.lock", b"")
    store.ensure_writable()
    expected = sorted([f"d/{i}.bin" for i in range(5)] + [f"d/{i}.lock" for i in range(5)])
    assert _all_local_files(tmp_path) == expected


def _failing_write(monkeypatch, exc: BaseException, after: int = 1):
    """Make os.write write ``after`` chunks for real, then raise ``exc``."""
    real_write = os.write
    calls = {"n": 0}

    def write(fd, data):
        calls["n"] += 1
        if calls["n"] > after:
            raise exc
        return real_write(fd, data)

    monkeypatch.setattr(os, "write", write)


@pytest.mark.parametrize(
    "exc, expected",
    [(OSError(errno.EIO, "I/O error"), StorageError), (RuntimeError("worker killed"), RuntimeError)],
)
def test_local_write_failing_midway_leaves_old_file_and_no_temp(tmp_path, monkeypatch, exc, expected):
    store = Storage.from_uri(str(tmp_path))
    store.write_bytes("frames/0001.png", b"old content")
    with monkeypatch.context() as patch:
        _failing_write(patch, exc)
        with pytest.raises(expected):
            store.write_bytes("frames/0001.png", os.urandom(3 * MIB))
        with pytest.raises(expected):
            store.write_bytes("frames/0002.png", os.urandom(3 * MIB))
    assert store.read_bytes("frames/0001.png") == b"old content"
    assert _all_local_files(tmp_path) == ["frames/0001.png"]


def test_full_disk_is_a_storage_error(tmp_path, monkeypatch):
    store = Storage.from_uri(str(tmp_path / "out"))
    _failing_write(monkeypatch, OSError(errno.ENOSPC, os.strerror(errno.ENOSPC)), after=0)
    with pytest.raises(StorageError, match=r"no space left on device \(ENOSPC\)") as info:
        store.write_bytes("a/b.png", b"x" * 100)
    assert str(tmp_path / "out" / "a" / "b.png") in str(info.value)
    assert "\n" not in str(info.value)
    with pytest.raises(StorageError, match=r"not writable: no space left on device"):
        store.ensure_writable()
    monkeypatch.undo()
    assert _all_local_files(tmp_path) == []


def test_local_exclusive_create_races(tmp_path):
    store = Storage.from_uri(str(tmp_path))
    results: list[bool] = []
    barrier = threading.Barrier(8)

    def claim(i: int) -> None:
        barrier.wait()
        results.append(store.create_exclusive("claim", str(i).encode()))

    threads = [threading.Thread(target=claim, args=(i,)) for i in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sorted(results) == [False] * 7 + [True]
    assert _all_local_files(tmp_path) == ["claim"]


def test_unwritable_roots(tmp_path):
    blocker = tmp_path / "a-file"
    blocker.write_bytes(b"")
    under_file = Storage.from_uri(str(blocker / "out"))
    with pytest.raises(StorageError, match="not a directory") as info:
        under_file.ensure_writable()
    assert str(blocker / "out") in str(info.value)
    with pytest.raises(StorageError, match="cannot write .*a-file/out/x.bin"):
        under_file.write_bytes("x.bin", b"1")
    with pytest.raises(StorageError, match="not a directory"):
        Storage.from_uri(str(blocker)).ensure_writable()  # the root is itself a file
    with pytest.raises(StorageError, match="/proc/idda-out"):
        Storage.from_uri("/proc/idda-out").ensure_writable()


# -- URIs and credentials --------------------------------------------------------------


@pytest.mark.parametrize(
    "uri, message",
    [
        ("gs://bucket/x", "expected a local path, file:///abs/path, s3://bucket/prefix"),
        ("http://host/x", "scheme 'http'"),
        ("", "empty output root"),
        ("s3://", "no valid bucket"),
        ("s3://Bad_Bucket/x", "no valid bucket"),
        ("s3://bucket/a/../b", "'..'"),
        ("file://otherhost/x", "no host"),
    ],
)
def test_bad_uris(uri, message):
    with pytest.raises(StorageError, match=message.replace("(", r"\(").replace(".", r"\.")):
        Storage.from_uri(uri)


@pytest.mark.parametrize(
    "uri",
    [
        "s3://AKIAEXAMPLE:supersecretvalue@bucket/prefix",
        "s3://supersecretvalue@bucket/prefix",
        "s3://bucket/prefix?access_key=AKIAEXAMPLE&secret_key=supersecretvalue",
        "gs://AKIAEXAMPLE:supersecretvalue@bucket/prefix",
    ],
)
def test_uri_credentials_are_rejected_without_echo(uri):
    with pytest.raises(StorageError) as info:
        Storage.from_uri(uri)
    assert "supersecretvalue" not in str(info.value)
    assert "AKIAEXAMPLE" not in str(info.value)


def test_endpoint_from_environment(monkeypatch):
    for name in ("IDDA_S3_ENDPOINT", "AWS_ENDPOINT_URL_S3", "AWS_ENDPOINT_URL", "AWS_REGION"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("AWS_DEFAULT_REGION", "eu-west-1")
    monkeypatch.setenv("AWS_ENDPOINT_URL", "http://generic:1")
    monkeypatch.setenv("AWS_ENDPOINT_URL_S3", "http://s3-specific:2")
    store = Storage.from_uri("s3://bucket/p")
    assert (store._s3.endpoint, store._s3.scheme, store._s3.region) == ("s3-specific:2", "http", "eu-west-1")
    monkeypatch.setenv("IDDA_S3_ENDPOINT", "minio.local:9000")
    store = Storage.from_uri("s3://bucket/p")
    assert (store._s3.endpoint, store._s3.scheme) == ("minio.local:9000", "https")
    # The endpoint travels with the pickle; credentials do not.
    monkeypatch.delenv("IDDA_S3_ENDPOINT")
    assert pickle.loads(pickle.dumps(store))._s3.endpoint == "minio.local:9000"
    monkeypatch.setenv("IDDA_S3_ENDPOINT", "http://user:supersecretvalue@minio.local:9000")
    with pytest.raises(StorageError, match="embeds credentials") as info:
        Storage.from_uri("s3://bucket/p")
    assert "supersecretvalue" not in str(info.value)


def test_credentials_never_in_strings(monkeypatch):
    secret = "wJalrXUtnFEMI-K7MDENG-bPxRfiCYEXAMPLEKEY"
    monkeypatch.setenv("AWS_ACCESS_KEY_ID", "AKIAIOSFODNN7EXAMPLE")
    monkeypatch.setenv("AWS_SECRET_ACCESS_KEY", secret)
    monkeypatch.setenv("AWS_SESSION_TOKEN", "session-token-value")
    store = Storage.from_uri("s3://bucket/prefix")
    produced = [repr(store), str(store), store.uri, store.join("a/b"), store.path("a/b")]
    payload = pickle.dumps(store)
    for value in (secret, "AKIAIOSFODNN7EXAMPLE", "session-token-value"):
        assert all(value not in text for text in produced)
        assert value.encode() not in payload
    assert redact(f"failed with key {secret} at s3://u:p@host/x") == "failed with key *** at s3://***@host/x"


def test_storage_error_pickles():
    err = StorageError("cannot write /x: no space left on device (ENOSPC)", cause="no space")
    clone = pickle.loads(pickle.dumps(err))
    assert str(clone) == str(err) and isinstance(clone, StorageError)


# -- S3 only ---------------------------------------------------------------------------


def test_s3_large_object_is_staged_and_published(s3_server):  # noqa: F811
    store = Storage.from_uri(s3_server.uri("large"))
    data = os.urandom(storage_fs.S3_SINGLE_PUT_MAX + MIB)
    store.write_bytes("big/obj.bin", data)
    assert store.size("big/obj.bin") == len(data)
    assert store.sha256("big/obj.bin") == sha256_bytes(data)
    assert _raw_keys(store) == [store.path("big/obj.bin")]


def test_s3_failed_large_write_leaves_nothing(s3_server, monkeypatch):  # noqa: F811
    store = Storage.from_uri(s3_server.uri("failing"))
    store.write_bytes("obj.bin", b"old")

    def write_half_then_fail(stream, data):
        stream.write(data[: len(data) // 2])
        raise OSError(errno.ECONNRESET, "connection reset by peer")

    monkeypatch.setattr(storage_fs, "_write_all", write_half_then_fail)
    data = os.urandom(storage_fs.S3_SINGLE_PUT_MAX + MIB)
    with pytest.raises(StorageError, match="cannot write s3://.*/failing/obj.bin"):
        store.write_bytes("obj.bin", data)
    with pytest.raises(StorageError):
        store.write_bytes("new.bin", data)
    assert store.read_bytes("obj.bin") == b"old"
    assert _raw_keys(store) == [store.path("obj.bin")]


def test_s3_missing_bucket(s3_server):  # noqa: F811
    store = Storage.from_uri("s3://no-such-bucket-here/x")
    with pytest.raises(StorageError, match="no-such-bucket-here.*bucket does not exist") as info:
        store.ensure_writable()
    with pytest.raises(StorageError, match="bucket does not exist") as info2:
        store.write_bytes("a.bin", b"1")
    for err in (info.value, info2.value):
        assert SECRET_KEY not in str(err) and SECRET_KEY not in repr(err)
    assert store.list_files() == []
    assert not store.exists("a.bin")


def test_remove_stale_temp_only_touches_matching_temp_files(tmp_path):
    from storage.atomic import temp_path

    storage = Storage.from_uri(str(tmp_path))
    storage.write_bytes("S/rgb/0001_000_S.png", b"kept")
    folder = tmp_path / "S" / "rgb"
    stale = temp_path(str(folder / "0001_003_S.png"))
    other = temp_path(str(folder / "0002_000_S.png"))
    for path in (stale, other):
        with open(path, "wb") as f:
            f.write(b"partial")
    assert storage.remove_stale_temp("S/rgb", "0001_") == 1
    assert not os.path.exists(stale) and os.path.exists(other)
    assert storage.read_bytes("S/rgb/0001_000_S.png") == b"kept"
    assert storage.remove_stale_temp("S/missing", "") == 0


def test_s3_listing_is_one_delimited_list_then_each_folder_flat(tmp_path):
    """list_sizes on S3: one delimited LIST of the folder, then one flat listing per
    folder below it (pages of 1,000 keys), never one LIST per nested folder; the
    same files and sizes as the same tree on local disk."""
    from tests.s3_counter import counting_s3_server

    files = {f"top/{a}/{b}/{c}/f{i}.bin": i for a in ("x", "y") for b in ("p", "q") for c in ("1", "2", "3")
             for i in range(4)}
    files.update({"top/loose.bin": 7, "top/x/deep/.f.bin." + "0" * 32 + ".tmp": 1})  # a writer's temp file
    files.update({f"top/z/{i:04d}.bin": 1 for i in range(1001)})  # two pages flat
    local = Storage.from_uri(str(tmp_path / "root"))
    with counting_s3_server() as (server, counter):
        remote = Storage.from_uri(server.uri("root"))
        for rel, size in files.items():
            local.write_bytes(rel, b"x" * size)
            remote.write_bytes(rel, b"x" * size)
        counter.reset()
        listed = remote.list_sizes("top/")
        assert counter.counts() == {"GET": 1 + 1 + 1 + 2}  # top/ delimited; x, y flat; z flat in two pages
        neighbour = Storage.from_uri(server.uri("root2"))  # a root whose name extends this one's
        neighbour.write_bytes("top/x2/n.bin", b"n")
        remote.write_bytes("top/x2/own.bin", b"o")  # a folder whose name extends x's
        assert remote.list_sizes("top/x/") == {rel: size for rel, size in files.items()
                                              if rel.startswith("top/x/") and not rel.endswith(".tmp")}
        assert "top/x2/n.bin" not in remote.list_sizes("") and "top/x2/own.bin" in remote.list_sizes("")
    assert listed == local.list_sizes("top/")
    assert listed == {rel: size for rel, size in files.items() if not rel.endswith(".tmp")}


def test_read_listed_is_one_get_on_s3_and_fails_as_reads_do(monkeypatch):
    """Storage.read_listed: the same bytes as read_bytes in one GET on S3; a missing object is
    FileNotFoundError; an unreachable endpoint one StorageError naming the cause; without
    botocore it reads through pyarrow (HEAD then GET)."""
    import storage.s3get as s3get
    from tests.s3_counter import counting_s3_server

    with counting_s3_server() as (server, counter):
        remote = Storage.from_uri(server.uri("root"))
        remote.write_bytes("a/b.bin", b"payload" * 1000)
        counter.reset()
        assert remote.read_listed("a/b.bin", 7000) == remote.read_bytes("a/b.bin")
        assert counter.counts() == {"GET": 2, "HEAD": 1}  # read_listed: GET; read_bytes: HEAD and GET
        with pytest.raises(FileNotFoundError):
            remote.read_listed("a/gone.bin", 10)
        monkeypatch.setattr(s3get, "client_for", lambda config: None)
        counter.reset()
        assert remote.read_listed("a/b.bin", 7000) == b"payload" * 1000
        assert counter.counts() == {"GET": 1, "HEAD": 1}
        monkeypatch.undo()
    import socket

    with socket.socket() as sock:  # a port nothing listens on
        sock.bind(("127.0.0.1", 0))
        dead = sock.getsockname()[1]
    monkeypatch.setenv("AWS_ENDPOINT_URL_S3", f"http://127.0.0.1:{dead}")
    monkeypatch.setenv("AWS_ACCESS_KEY_ID", "k")
    monkeypatch.setenv("AWS_SECRET_ACCESS_KEY", "s")
    monkeypatch.setenv("AWS_REGION", "us-east-1")
    with pytest.raises(StorageError, match="cannot read .*cannot reach the S3 endpoint"):
        Storage.from_uri("s3://idda-test/root").read_listed("a/b.bin", 7000)
