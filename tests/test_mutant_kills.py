"""Tests written for what `make mutants` found the fast tests let through
(docs/mutants.md lists each survivor and the test here that now kills it).

Small and fast, no Ray: each names the promise the mutant broke.
"""

from __future__ import annotations

import errno
import os

import pytest

from storage import atomic

# ----------------------------------------------------------------- storage/atomic ----


def test_exclusive_write_without_hard_links_creates_the_file_once(monkeypatch, tmp_path):
    """Where hard links are unsupported (EPERM on some network file systems),
    exclusive_write falls back to O_EXCL on the name itself: still exclusive,
    the whole content written, no temp file left; another errno is an error."""
    def no_link(src, dst):
        raise OSError(errno.EPERM, "links not supported")

    monkeypatch.setattr(os, "link", no_link)
    target = tmp_path / "d" / "lease.json"
    assert atomic.exclusive_write(str(target), b"first") is True
    assert target.read_bytes() == b"first"
    assert atomic.exclusive_write(str(target), b"second") is False
    assert target.read_bytes() == b"first"
    assert os.listdir(target.parent) == ["lease.json"]

    def broken_link(src, dst):
        raise OSError(errno.EIO, "disk error")

    monkeypatch.setattr(os, "link", broken_link)
    with pytest.raises(OSError) as raised:
        atomic.exclusive_write(str(tmp_path / "d" / "other.json"), b"x")
    assert raised.value.errno == errno.EIO
    assert os.listdir(target.parent) == ["lease.json"]  # nor a temp file, nor a partial one


def test_a_failed_rename_leaves_no_temp_file_and_raises_its_own_error(monkeypatch, tmp_path):
    """atomic_write removes its temp file when the rename fails (a folder in
    the way), and when the temp file is already gone (a cleaner raced it) the
    rename's own error reaches the caller, not one from the clean-up."""
    blocked = tmp_path / "part.parquet"
    (blocked / "inside").mkdir(parents=True)
    with pytest.raises(OSError):
        atomic.atomic_write(str(blocked), b"rows")
    assert sorted(os.listdir(tmp_path)) == ["part.parquet"]

    def replace_after_a_cleaner(src, dst):
        os.unlink(src)
        raise OSError(errno.EIO, "disk error")

    monkeypatch.setattr(os, "replace", replace_after_a_cleaner)
    with pytest.raises(OSError) as raised:
        atomic.atomic_write(str(tmp_path / "run.json"), b"{}")
    assert raised.value.errno == errno.EIO
    assert sorted(os.listdir(tmp_path)) == ["part.parquet"]


@pytest.mark.parametrize("how", ["atomic_write", "exclusive_write"])
def test_written_files_get_the_usual_mode_never_executable(tmp_path, how):
    """Frames, parts and run.json are created 0o666 less the umask (0o644 here),
    as any file a user makes: not executable, not writable by others."""
    old = os.umask(0o022)
    try:
        getattr(atomic, how)(str(tmp_path / "f.png"), b"png")
    finally:
        os.umask(old)
    assert (tmp_path / "f.png").stat().st_mode & 0o777 == 0o644


# ---------------------------------------------------------------- manifests/lease ----


def test_lease_ttl_from_the_environment():
    from roots.lease import TTL_ENV, TTL_S, ttl_from_env

    assert ttl_from_env({}) == TTL_S
    assert ttl_from_env({TTL_ENV: "2.5"}) == 2.5
    assert ttl_from_env({TTL_ENV: "0.5"}) == 0.5  # the tests' short leases: any positive number, below 1 s too
    for bad in ("0", "-3", "soon", "nan", ""):
        with pytest.raises(ValueError, match=f"^{TTL_ENV} must be a positive number of seconds, got '{bad}'$"):
            ttl_from_env({TTL_ENV: bad})


def test_a_lease_is_described_by_purpose_owner_and_time_left():
    import time

    from roots.lease import describe

    line = describe({"purpose": "repair", "owner": "host-7-ab12", "expires": time.time() + 3600})
    assert line in {f"repair by host-7-ab12 (lease expires in {s} s unless renewed)" for s in (3598, 3599, 3600)}
    assert describe({"expires": time.time() - 50}) == "? by ? (lease expires in 0 s unless renewed)"


def _this_host_lease(pid) -> dict:
    import socket
    import time

    from roots.lease import _pid_namespace

    return {"owner": "o", "host": socket.gethostname(), "pidns": _pid_namespace(), "pid": pid,
            "purpose": "produce", "expires": time.time() + 60}


@pytest.mark.parametrize("pid", [0, -1, "1234", None])
def test_a_lease_whose_pid_is_odd_is_judged_by_its_expiry_alone(pid):
    """Only a real pid that is gone makes a live lease dead: an odd one proves nothing."""
    from roots.lease import is_live

    assert is_live(_this_host_lease(pid))


def test_a_lease_of_another_users_process_on_this_host_is_live(monkeypatch):
    """os.kill(pid, 0) refused (EPERM): the process exists, so its lease is live."""
    from roots import lease

    def refused(pid, sig):
        raise PermissionError(errno.EPERM, "not yours")

    monkeypatch.setattr(lease.os, "kill", refused)
    assert lease.is_live(_this_host_lease(4321))

    def gone(pid, sig):
        raise ProcessLookupError(errno.ESRCH, "no such process")

    monkeypatch.setattr(lease.os, "kill", gone)
    assert not lease.is_live(_this_host_lease(4321))



@pytest.mark.parametrize("other", ["pidns", "host"])
def test_a_lease_of_another_pid_namespace_or_host_is_judged_by_its_expiry_alone(monkeypatch, other):
    """A pid means nothing outside its own namespace (a container) or host: such a
    lease is live until it expires, even where no process of that pid runs here."""
    from roots import lease

    assert lease.is_live(_this_host_lease(os.getpid()))  # our own process, really running

    def gone(pid, sig):
        raise ProcessLookupError(errno.ESRCH, "no such process")

    monkeypatch.setattr(lease.os, "kill", gone)
    assert not lease.is_live(_this_host_lease(4321))
    info = {**_this_host_lease(4321), other: "pid:[1]" if other == "pidns" else "elsewhere"}
    assert lease.is_live(info)


def test_taking_over_a_lease_warns_only_where_its_process_is_gone(tmp_path, caplog):
    """A torn or expired exclusive lease is taken over quietly; one live by its expiry
    whose process on this host is gone is taken over with a warning naming its pid."""
    import json
    import logging
    import time

    from roots.lease import EXCLUSIVE, acquire_exclusive, exclusive_holder
    from storage import Storage

    storage = Storage.from_uri(str(tmp_path))
    dead = _this_host_lease(os.getpid())
    for body, warned in ((b"{torn", False), (json.dumps({**dead, "expires": time.time() - 5}).encode(), False),
                         (json.dumps({**dead, "pid": 2 ** 22 + 17}).encode(), True)):
        storage.write_bytes(EXCLUSIVE, body)
        caplog.clear()
        with caplog.at_level(logging.WARNING, logger="roots.lease"):
            with acquire_exclusive(storage, "repair", owner="me") as held:
                assert exclusive_holder(storage)["owner"] == "me" == held.owner
        assert exclusive_holder(storage) is None
        said = [r.getMessage() for r in caplog.records]
        assert said == ([f"took over the lease of produce by o on {tmp_path}: its process {2 ** 22 + 17} on this "
                         "host is gone"] if warned else []), body


def test_a_refreshed_producer_lease_keeps_the_generation_it_registered_under(tmp_path):
    from roots.lease import bump_generation, read_lease, register_producer
    from storage import Storage

    storage = Storage.from_uri(str(tmp_path))
    bump_generation(storage)
    producer = register_producer(storage, owner="p")
    try:
        producer.refresh()
        info = read_lease(storage, producer.rel)
        assert (info["owner"], info["purpose"], info["generation"]) == ("p", "produce", 1)
    finally:
        producer.release()


def test_a_lease_is_kept_alive_by_a_daemon_thread_and_released_for_good(tmp_path):
    """The refresher runs every quarter of the TTL from a daemon thread (a killed
    producer's interpreter never waits for it); release stops and joins it, then
    removes the lease file, which then stays gone."""
    import time

    from roots.lease import read_lease, register_producer
    from storage import Storage

    storage = Storage.from_uri(str(tmp_path))
    producer = register_producer(storage, owner="p", ttl_s=0.4)
    first = read_lease(storage, producer.rel)
    assert (first["owner"], first["purpose"], first["generation"]) == ("p", "produce", 0)
    assert producer._thread.daemon and producer._thread.name == "lease-produce"
    time.sleep(0.5)
    assert read_lease(storage, producer.rel)["expires"] > first["expires"]  # refreshed meanwhile
    producer.release()
    assert not producer._thread.is_alive()
    assert not storage.exists(producer.rel)
    time.sleep(0.3)
    assert not storage.exists(producer.rel)  # no refresh brings it back


def test_release_waits_for_a_refresh_under_way(tmp_path):
    """A refresh still writing after release returned could bring the lease back."""
    import time

    from roots.lease import register_producer
    from storage import Storage

    producer = register_producer(Storage.from_uri(str(tmp_path)), owner="p", ttl_s=0.2)
    steps = []

    def slow_refresh():
        steps.append("start")
        time.sleep(0.4)
        steps.append("end")

    producer.refresh = slow_refresh
    time.sleep(0.15)  # the refresher is inside a refresh now
    producer.release()
    assert steps == ["start", "end"]


def test_release_leaves_a_lease_that_is_no_longer_ours(tmp_path):
    from roots.lease import EXCLUSIVE, _body, acquire_exclusive, read_lease
    from storage import Storage

    storage = Storage.from_uri(str(tmp_path))
    held = acquire_exclusive(storage, "compact", owner="me")
    storage.write_bytes(EXCLUSIVE, _body("someone", "repair", 60))  # taken over meanwhile
    held.release()
    assert read_lease(storage, EXCLUSIVE)["owner"] == "someone"


def test_a_locked_root_is_refused_at_once_unless_asked_to_wait(monkeypatch, tmp_path):
    from roots import lease
    from storage import Storage

    storage = Storage.from_uri(str(tmp_path))
    with lease.acquire_exclusive(storage, "repair", owner="holder") as held:
        assert held.purpose == "repair" and lease.exclusive_holder(storage)["purpose"] == "repair"
        waits = []
        monkeypatch.setattr(lease.time, "sleep", waits.append)
        with pytest.raises(lease.LeaseError, match=f"^{tmp_path} is locked: repair by holder "):
            lease.acquire_exclusive(storage, "compact")
        assert waits == []  # no wait by default


def test_an_owner_names_its_host_and_process():
    import re
    import socket

    from roots.lease import new_owner

    assert re.fullmatch(f"{re.escape(socket.gethostname())}-{os.getpid()}-[0-9a-f]{{8}}", new_owner())
    assert new_owner() != new_owner()


class _NotLocal:
    """A local Storage taken the way an S3 root is (no hard links): for the S3 lease protocol."""

    is_local = False

    def __init__(self, storage):
        self._storage = storage

    def __getattr__(self, name):
        return getattr(self._storage, name)


def test_an_s3_exclusive_lease_is_won_by_the_writer_that_reads_itself_back(monkeypatch, tmp_path):
    """S3 has no exclusive create: the holder writes its lease, waits, reads it back;
    of two writers only the last one's lease reads back as its own."""
    from roots import lease
    from storage import Storage

    storage = _NotLocal(Storage.from_uri(str(tmp_path)))
    assert lease._create(storage, lease.EXCLUSIVE, "first", "repair", 60) is True  # (settles S3_SETTLE_S)
    assert lease.read_lease(storage, lease.EXCLUSIVE)["owner"] == "first"
    assert lease._create(storage, lease.EXCLUSIVE, "second", "repair", 60) is False  # it exists
    storage.delete(lease.EXCLUSIVE)
    waits = []

    def overwritten_meanwhile(seconds):
        waits.append(seconds)
        storage.write_bytes(lease.EXCLUSIVE, lease._body("racer", "repair", 60))

    monkeypatch.setattr(lease.time, "sleep", overwritten_meanwhile)
    assert lease._create(storage, lease.EXCLUSIVE, "third", "repair", 60) is False
    assert waits == [lease.S3_SETTLE_S] and lease.read_lease(storage, lease.EXCLUSIVE)["owner"] == "racer"


# ------------------------------------------------------------ manifests/runrecord ----


def _record(**config_changes) -> dict:
    from pipeline.settings import PlanConfig, RunConfig

    config = RunConfig(plan=PlanConfig(domains="T01_CN_A", frames_per_scenario=3, width=64, height=36),
                       world="test").to_dict()
    for key, value in config_changes.items():
        if value is _DROP:
            config.pop(key, None)
        else:
            config[key] = value
    return {"config": config}


_DROP = object()


@pytest.mark.parametrize("record, says", [
    ([], "is not a run record"),
    ({"config": []}, "is not a run record"),
    (_record(width=_DROP), "its config lacks 'width'"),
    (_record(seed=_DROP), "its config lacks 'seed'"),
    (_record(domains=_DROP), "its config lacks 'domains'"),
    (_record(width="64"), "config 'width' is '64'"),
    (_record(seed=True), "config 'seed' is True"),
    (_record(scale="1"), "config 'scale' is '1'"),
    (_record(pairing=1.0), "config 'pairing' is 1.0"),
    (_record(colour="red", size=3), "unknown config keys colour, size"),
    ({**_record(), "history": {}}, "'history' must be a list of configs"),
    ({**_record(), "history": [{}, 3]}, "'history' must be a list of configs"),
    ({**_record(), "layout": "nested"}, "unknown file layout 'nested'"),
    ({**_record(), "layout": True}, "unknown file layout True"),
])
def test_a_run_record_of_the_wrong_shape_is_refused_naming_what(record, says):
    from pipeline.settings import CONFIG_SHAPE
    from roots.run_file import RunRecordError, check_record

    with pytest.raises(RunRecordError) as raised:
        check_record(record, "root/run.json", CONFIG_SHAPE)
    assert str(raised.value).startswith("root/run.json ") and says in str(raised.value)


def test_a_run_record_without_optional_keys_or_checksum_reads_as_an_old_root():
    from pipeline.settings import CONFIG_SHAPE, OPTIONAL_CONFIG
    from roots.run_file import check_record

    old = _record(**{key: _DROP for key in OPTIONAL_CONFIG}, scale=_DROP, frames_per_scenario=_DROP)
    assert check_record(old, "root/run.json", CONFIG_SHAPE) is old
    with_history = {**_record(), "history": [{"seed": 1}], "layout": 2}
    assert check_record(with_history, "root/run.json", CONFIG_SHAPE) is with_history


def test_run_json_that_is_not_a_file_or_not_json_is_damaged(tmp_path):
    from roots.run_file import RunRecordError, read_record
    from manifests.schema import RUN_FILE
    from storage import Storage

    storage = Storage.from_uri(str(tmp_path))
    assert read_record(storage) is None
    (tmp_path / RUN_FILE).mkdir()
    with pytest.raises(RunRecordError, match=r"run\.json is not a regular file$"):
        read_record(storage)
    (tmp_path / RUN_FILE).rmdir()
    for damaged in (b"{not json", b"\xff\xfe"):
        (tmp_path / RUN_FILE).write_bytes(damaged)
        with pytest.raises(RunRecordError, match=r"run\.json is not valid JSON: "):
            read_record(storage)
    (tmp_path / RUN_FILE).write_bytes(b"[]")
    with pytest.raises(RunRecordError, match=f"^{tmp_path}/run\\.json is not a run record"):
        read_record(storage)


# --------------------------------------------------------------- pipeline/repair ----

REPAIR_PLAN = dict(domains="T01_CN_A", frames_per_scenario=3, width=64, height=36, seed=5)


@pytest.fixture(scope="module")
def tiny_root(tmp_path_factory):
    """One 3-frame episode at 64x36, rendered without Ray, its index written: copied by each test."""
    from pipeline.settings import PlanConfig, RunConfig
    from tests.roots import render_root

    root = tmp_path_factory.mktemp("tiny") / "root"
    render_root(root, RunConfig(plan=PlanConfig(**REPAIR_PLAN), world="test"), compact=True)
    return root


def _copy_of(tiny_root, tmp_path):
    import shutil

    from storage import Storage

    shutil.copytree(tiny_root, tmp_path / "root", symlinks=True)
    return tmp_path / "root", Storage.from_uri(str(tmp_path / "root"))


def _produce_config(root, **plan_changes):
    from pipeline.settings import PlanConfig, ProduceConfig, RunConfig

    return ProduceConfig(run=RunConfig(plan=PlanConfig(**{**REPAIR_PLAN, **plan_changes}), world="test"),
                         out=str(root), workers=1)


def test_repair_drops_the_damaged_episode_strays_and_a_bad_index_and_rewrites_run_json(tiny_root, tmp_path, caplog):
    import logging

    from manifests.reader import done_episodes, episode_parts
    from roots.run_file import read_record
    from manifests.schema import RUN_FILE, index_path
    from pipeline.planner import make_plan
    from pipeline.repair import repair_alone

    root, storage = _copy_of(tiny_root, tmp_path)
    frame = sorted((root / "T01_CN_A").rglob("*.png"))[0]
    frame.write_bytes(frame.read_bytes()[:-4] + b"XXXX")
    stray = root / "T01_CN_A" / "e0009" / "rgb" / "0009_000_T01_CN_A.png"  # ours by name, listed by no part
    stray.parent.mkdir(parents=True)
    stray.write_bytes(b"stray")
    (root / RUN_FILE).write_bytes(b"{damaged")
    config = _produce_config(root)
    plan = make_plan(config.run.plan)
    from dataclasses import replace

    unplanned = type(plan)(plan.config, (replace(plan.episodes[0], episode=1),))  # its scenario, another episode
    from roots.lease import register_producer

    me = register_producer(storage, owner="me")  # produce --repair: our own producer lease is live
    try:
        with caplog.at_level(logging.WARNING, logger="pipeline.repair"):
            touched = repair_alone(storage, config, unplanned, owner="me")
    finally:
        me.release()
    assert "T01_CN_A_e0000 is damaged but not in the current plan; it stays pending" in [
        r.getMessage() for r in caplog.records if r.name == "pipeline.repair"]
    assert sorted(touched) == sorted(["T01_CN_A/e0000", RUN_FILE])
    assert episode_parts(storage, "T01_CN_A", 0) == [] and done_episodes(storage) == set()
    assert not storage.exists(index_path("T01_CN_A")) and not stray.exists()
    assert read_record(storage)["config"]["seed"] == 5  # rewritten from the run's options
    assert not (root / "_lease" / "exclusive.json").exists()


def test_repair_drops_a_bad_index_alone_and_names_it(tiny_root, tmp_path):
    from manifests.reader import done_episodes
    from manifests.schema import index_path
    from pipeline.planner import make_plan
    from pipeline.repair import repair_alone

    root, storage = _copy_of(tiny_root, tmp_path)
    storage.write_bytes(index_path("T01_CN_A"), b"not parquet")
    config = _produce_config(root)
    assert repair_alone(storage, config, make_plan(config.run.plan), owner="me") == [index_path("T01_CN_A")]
    assert not storage.exists(index_path("T01_CN_A")) and done_episodes(storage) == {("T01_CN_A", 0)}


def test_repair_refuses_a_link_or_another_runs_part_and_deletes_nothing(tiny_root, tmp_path):
    from manifests.reader import episode_parts
    from roots.contract import RootError
    from manifests.schema import PART_SCHEMA
    from manifests.part_file import read_part_file
    from manifests.writer import write_part
    from pipeline.planner import make_plan
    from pipeline.repair import _repair
    from pipeline.provenance import RunConfigError

    root, storage = _copy_of(tiny_root, tmp_path)
    config = _produce_config(root)
    plan = make_plan(config.run.plan)
    frame = sorted((root / "T01_CN_A").rglob("*.png"))[0]
    frame.write_bytes(b"damaged")
    before = _files(root)
    (frame.parent / "elsewhere").symlink_to(tmp_path)
    with pytest.raises(RootError, match=r"/T01_CN_A/.*/elsewhere is a symbolic link; repair never follows a link out of "
                       "the root and deletes nothing: replace the link with the files it points to, or remove it, "
                       "and run again$"):
        _repair(storage, config, plan, owner="me")
    (frame.parent / "elsewhere").unlink()
    assert _files(root) == before
    (rel,) = episode_parts(storage, "T01_CN_A", 0)
    table = read_part_file(storage, rel, PART_SCHEMA)
    write_part(storage, "T01_CN_A", 0, table.set_column(table.schema.get_field_index("seed"), "seed",
                                                        [[7] * len(table)]).cast(table.schema))
    (root / "run.json").unlink()  # without run.json, the rows are checked against the command's own options
    before = _files(root)
    with pytest.raises(RunConfigError, match=r"_n3\.parquet holds frames of another run \(.*seed.*; 1 part\(s\) in all\); "
                       r"repair deleted nothing: check --seed/--width/--height, or move such parts out of the root$"):
        _repair(storage, config, plan, owner="me")
    assert _files(root) == before


def _files(root) -> dict[str, bytes]:
    """Every file under ``root`` but the leases, with its content (links not followed)."""
    out = {}
    for folder, _, files in os.walk(root):
        for name in files:
            path = os.path.join(folder, name)
            rel = os.path.relpath(path, root)
            if not rel.startswith("_lease"):
                with open(path, "rb") as f:
                    out[rel] = f.read()
    return out


def test_repair_waits_for_other_producers_and_nobody_starts_beside_a_repair(tiny_root, tmp_path):
    from roots.lease import LeaseError, acquire_exclusive, register_producer
    from pipeline.planner import make_plan
    from pipeline.repair import check_no_repair_running, repair_alone

    root, storage = _copy_of(tiny_root, tmp_path)
    config = _produce_config(root)
    other = register_producer(storage, owner="other")
    try:
        with pytest.raises(LeaseError, match="is being written by another producer \\(produce by other"):
            repair_alone(storage, config, make_plan(config.run.plan), owner="me")
    finally:
        other.release()
    assert not (root / "_lease" / "exclusive.json").exists()
    check_no_repair_running(storage)
    with acquire_exclusive(storage, "compact"):
        check_no_repair_running(storage)  # compaction does not delete frames
    with acquire_exclusive(storage, "repair"):
        with pytest.raises(LeaseError, match="is being repaired \\(repair by "):
            check_no_repair_running(storage)


# A run.json as this version writes it, kept byte for byte: a root made today must keep
# reading (and its checksum matching) whatever later changes how records are written.
KEPT_RUN_JSON = b"""{
  "checksum": "c24905eefd18621ac007f1b79f1f78256936814a6e891b966a0f878d620b0a56",
  "config": {
    "domains": "T01_CN_A",
    "frames_per_scenario": 3,
    "height": 36,
    "scale": null,
    "seed": 0,
    "width": 64
  },
  "layout": 2
}
"""


def test_a_kept_run_json_still_reads_and_is_written_again_byte_for_byte(tmp_path):
    import json

    from roots.run_file import RunRecordError, read_record, record_bytes
    from manifests.schema import RUN_FILE
    from storage import Storage

    storage = Storage.from_uri(str(tmp_path))
    (tmp_path / RUN_FILE).write_bytes(KEPT_RUN_JSON)
    record = read_record(storage)
    assert record["config"]["seed"] == 0 and record["layout"] == 2
    assert record_bytes(record) == KEPT_RUN_JSON  # same record, same bytes
    edited = KEPT_RUN_JSON.replace(b'"seed": 0', b'"seed": 1')
    (tmp_path / RUN_FILE).write_bytes(edited)
    with pytest.raises(RunRecordError, match="checksum does not match"):
        read_record(storage)
    unsealed = json.loads(KEPT_RUN_JSON)
    del unsealed["checksum"]  # a record from before checksums
    (tmp_path / RUN_FILE).write_text(json.dumps(unsealed))
    assert read_record(storage) == unsealed


def test_repair_needs_extend_for_another_config_and_verifies_only_its_plans_scenarios(tiny_root, tmp_path):
    """A repair with another (not frame-defining) config must say --extend; with
    it, it verifies and touches only the scenarios of its own plan."""
    from manifests.reader import done_episodes
    from pipeline.planner import make_plan
    from pipeline.repair import _repair
    from pipeline.provenance import RunConfigError

    root, storage = _copy_of(tiny_root, tmp_path)
    frame = sorted((root / "T01_CN_A").rglob("*.png"))[0]
    frame.write_bytes(b"damaged")
    config = _produce_config(root, domains="T01_HRN_A")
    with pytest.raises(RunConfigError, match="pass --extend to add to it"):
        _repair(storage, config, make_plan(config.run.plan), owner="me")
    from dataclasses import replace

    extend = replace(config, extend=True)
    assert _repair(storage, extend, make_plan(extend.run.plan), owner="me") == []
    assert done_episodes(storage) == {("T01_CN_A", 0)} and frame.read_bytes() == b"damaged"  # out of its scope


def test_repairs_verify_goes_to_the_cluster_and_workers_produce_was_given(monkeypatch, tmp_path):
    """`produce --repair --address A --workers N` verifies on A with N workers (not a private cluster)."""
    from dataclasses import replace

    from pipeline import verify_ray
    from pipeline.repair import verify_runner

    asked = []
    monkeypatch.setattr(verify_ray, "choose_runner", lambda **kwargs: asked.append(kwargs) or "runner")
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    config = replace(_produce_config(tmp_path), address="10.0.0.7:6379", workers=3)
    assert verify_runner(config) == "runner"
    assert asked == [{"address": "10.0.0.7:6379", "workers": 3}]


def test_repair_holds_the_exclusive_lease_as_a_repair_under_its_own_name(monkeypatch, tiny_root, tmp_path):
    """While it deletes, repair's lease says "repair" by its owner: producers starting meanwhile
    refuse (check_no_repair_running), and the lease is the one its owner releases."""
    from roots.lease import LeaseError, exclusive_holder
    from pipeline import repair
    from pipeline.planner import make_plan

    root, storage = _copy_of(tiny_root, tmp_path)
    held = []

    def look(storage, config, plan, owner):
        held.append(exclusive_holder(storage))
        with pytest.raises(LeaseError, match="is being repaired"):
            repair.check_no_repair_running(storage)
        return []

    monkeypatch.setattr(repair, "_repair", look)
    config = _produce_config(root)
    assert repair.repair_alone(storage, config, make_plan(config.run.plan), owner="me-1") == []
    assert [(h["purpose"], h["owner"]) for h in held] == [("repair", "me-1")]
    assert exclusive_holder(storage) is None


def test_repair_with_extend_records_the_extended_config(monkeypatch, tiny_root, tmp_path):
    from roots.run_file import read_record
    from pipeline import repair
    from pipeline.planner import make_plan

    root, storage = _copy_of(tiny_root, tmp_path)
    monkeypatch.setattr(repair, "_repair", lambda *args: [])  # nothing to drop: the record is what is checked
    config = _produce_config(root, domains="T01_CN_A,T01_HRN_A")
    from dataclasses import replace

    config = replace(config, extend=True)
    repair.repair_alone(storage, config, make_plan(config.run.plan), owner="me")
    record = read_record(storage)
    assert record["config"]["domains"] == "T01_CN_A,T01_HRN_A" and record["history"][0]["domains"] == "T01_CN_A"


# ------------------------------------------------------------ pipeline/episode_job ----


def test_a_producer_that_lost_its_lease_never_writes_the_part(monkeypatch, tmp_path):
    """The check before the write: a producer whose lease was taken over writes no
    part at all (not one that appears, then is deleted again)."""
    from roots.lease import LeaseLost, bump_generation, register_producer
    from manifests.synthetic import episode_table
    from pipeline import episode_job
    from storage import Storage
    from tests.test_caught_bugs import tiny_spec

    storage = Storage.from_uri(str(tmp_path / "root"))
    spec = tiny_spec()
    producer = register_producer(storage, ttl_s=60)
    written = []
    monkeypatch.setattr(episode_job, "write_part", lambda *args: written.append(args))
    try:
        bump_generation(storage)  # a repair took the root over
        with pytest.raises(LeaseLost, match="generation 0 -> 1"):
            episode_job.commit_part(storage, spec, episode_table(spec).to_pylist(), producer.fence)
    finally:
        producer.release()
    assert written == []


# ----------------------------------------------------------------- manifests/writer ----


class _AnyFrame:
    """A rendered frame whose every field is 0, its class counts given."""

    def __init__(self, class_counts):
        import collections

        from manifests.schema import FIELD_SOURCE

        self.index = 0
        self.class_counts = class_counts
        self.object_counts = collections.defaultdict(int)
        self.conditions = {name: 0.0 for name, source in FIELD_SOURCE.items() if source == "condition"}

    def __getattr__(self, name):
        return 0


def test_a_frame_row_refuses_unknown_outputs_and_wrong_class_counts_naming_the_frame():
    import re

    from domains.catalog import LABELS
    from manifests.part_file import ManifestError
    from manifests.writer import frame_row
    from tests.test_caught_bugs import tiny_spec

    spec = tiny_spec()
    pixels = spec.width * spec.height
    with pytest.raises(ManifestError, match=re.escape(f"{spec.key} frame 0: unknown outputs ['bogus']")):
        frame_row(spec, _AnyFrame([pixels] + [0] * (len(LABELS) - 1)), {"bogus": b"x"})
    with pytest.raises(ManifestError, match=re.escape(
            f"{spec.key} frame 0: class counts must be {len(LABELS)} values summing to {pixels}, got shape (2,) sum 3")):
        frame_row(spec, _AnyFrame([1, 2]), {})


def test_a_frame_row_names_the_frame_and_its_files():
    from domains.catalog import LABELS
    from manifests.writer import frame_row
    from storage import sha256_bytes
    from tests.test_caught_bugs import tiny_spec

    spec = tiny_spec()
    row = frame_row(spec, _AnyFrame([spec.width * spec.height] + [0] * (len(LABELS) - 1)), {"rgb": b"png"})
    assert (row["frame_id"], row["uid"], row["frame"]) == ("0000_000", f"0000_000_{spec.scenario}", 0)
    assert (row["rgb_path"], row["rgb_bytes"], row["rgb_sha256"]) == (
        f"{spec.scenario}/e0000/rgb/0000_000_{spec.scenario}.png", 3, sha256_bytes(b"png"))
    assert row["depth_raw_path"] is None and row["depth_raw_bytes"] is None


def test_read_part_reads_an_episodes_part_under_whichever_name(tmp_path):
    from manifests.schema import part_path
    from manifests.synthetic import episode_table
    from manifests.writer import part_bytes, write_part
    from manifests.reader import read_part
    from storage import Storage
    from tests.test_caught_bugs import tiny_spec

    storage = Storage.from_uri(str(tmp_path))
    spec = tiny_spec()
    table = episode_table(spec)
    storage.write_bytes(part_path(spec.scenario, spec.episode), part_bytes(table))  # an old root's name
    assert read_part(storage, spec.scenario, spec.episode).select(table.column_names).equals(table)  # + null rig columns
    write_part(storage, spec.scenario, spec.episode, table)  # the name that counts its rows
    assert storage.list_files(part_path(spec.scenario, spec.episode).rpartition("/")[0]) == [
        part_path(spec.scenario, spec.episode, len(table))]
    assert read_part(storage, spec.scenario, spec.episode).select(table.column_names).equals(table)


def test_a_part_is_zstd_with_statistics_and_no_arrow_schema():
    """What old roots' parts are, byte for byte: zstd pages, statistics (status and
    compaction read them), no stored Arrow schema (it halved footer reads' speed)."""
    import io

    import pyarrow.parquet as pq

    from manifests.synthetic import episode_table
    from manifests.writer import part_bytes
    from tests.test_caught_bugs import tiny_spec

    meta = pq.ParquetFile(io.BytesIO(part_bytes(episode_table(tiny_spec())))).metadata
    assert b"ARROW:schema" not in (meta.metadata or {})
    columns = [meta.row_group(0).column(i) for i in range(meta.num_columns)]
    assert {c.compression for c in columns} == {"ZSTD"}
    assert all(c.is_stats_set for c in columns)


# -------------------------------------------------------------- storage/checksum ----


def test_a_stream_is_hashed_a_chunk_at_a_time():
    """Storage.sha256 hashes a file of any size in bounded memory: each read asks for
    one chunk (1 MiB by default), never the whole stream at once."""
    import hashlib
    import io

    from storage.checksum import CHUNK, sha256_stream

    class Recording(io.BytesIO):
        def __init__(self, data):
            super().__init__(data)
            self.asked = []

        def read(self, size=-1):
            self.asked.append(size)
            return super().read(size)

    data = bytes(range(256)) * 12 + b"tail"  # 3076 bytes: three whole chunks of 1000 and a short one
    stream = Recording(data)
    assert sha256_stream(stream, chunk=1000) == hashlib.sha256(data).hexdigest()
    assert stream.asked == [1000, 1000, 1000, 1000, 1000]  # the fifth read finds the end
    stream = Recording(data)
    assert sha256_stream(stream) == hashlib.sha256(data).hexdigest()
    assert stream.asked == [CHUNK, CHUNK] and CHUNK == 1 << 20


# ------------------------------------------------------------- pipeline/provenance ----


def _tiny_root(tmp_path, plan=None, parts=True):
    """A root of TINY's run (or ``plan``'s): marker, run.json and, with ``parts``, its
    episode's part (synthetic rows: the files it lists do not exist)."""
    from manifests.writer import write_part
    from pipeline.planner import make_plan
    from pipeline.provenance import prepare_root
    from pipeline.settings import RunConfig
    from roots.contract import claim_root
    from storage import Storage
    from tests.test_caught_bugs import TINY
    from manifests.synthetic import episode_table

    storage = Storage.from_uri(str(tmp_path / "root"))
    claim_root(storage)
    config = RunConfig(plan=plan or TINY, world="test")
    prepare_root(storage, config)
    if parts:
        spec = make_plan(config.plan).episodes[0]
        write_part(storage, spec.scenario, spec.episode, episode_table(spec))
    return storage, config


def test_a_new_run_record_names_its_config_versions_encoder_and_layout(tmp_path):
    import platform
    from importlib import metadata

    from manifests.layout import LAYOUT_KEY, NEW_ROOT_LAYOUT
    from outputs.encoding import encoder_identity
    from pipeline.provenance import _PACKAGES, git_revision, recorded_config
    from roots.run_file import read_record

    storage, config = _tiny_root(tmp_path, parts=False)
    record = read_record(storage)
    assert record["config"] == config.to_dict() and record["history"] == [config.to_dict()]
    assert record["versions"]["python"] == platform.python_version()
    assert set(record["versions"]) == {"python", *_PACKAGES}
    assert record["versions"]["numpy"] == metadata.version("numpy")
    assert record["git_revision"] == git_revision() != "unknown"
    assert record["encoder"] == encoder_identity("png") and record[LAYOUT_KEY] == NEW_ROOT_LAYOUT
    assert recorded_config(record) == config


def test_the_git_revision_says_dirty_and_unknown_outside_a_checkout(monkeypatch, tmp_path):
    """run.json's revision is the checkout's HEAD, "-dirty" with tracked changes,
    found from the code's own folder whatever the working directory; no git: "unknown"."""
    import subprocess
    from pathlib import Path

    from pipeline import provenance

    head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=Path(provenance.__file__).parent,
                          capture_output=True, text=True, check=True).stdout.strip()
    real = subprocess.run

    def with_status(out):
        def run(args, **kwargs):
            done = real(args, **kwargs)
            if args[:2] == ["git", "status"] and "--porcelain" in args and done.returncode == 0:
                done.stdout = out  # the short format's lines, as a checkout with (or without) changes gives
            return done
        return run

    monkeypatch.chdir(tmp_path)  # not a checkout: the code's folder is asked
    monkeypatch.setattr(provenance.subprocess, "run", with_status(" M pipeline/cli.py\n"))
    assert provenance.git_revision() == head + "-dirty"
    monkeypatch.setattr(provenance.subprocess, "run", with_status(""))
    assert provenance.git_revision() == head

    def no_git(args, **kwargs):
        raise FileNotFoundError(args[0])

    monkeypatch.setattr(provenance.subprocess, "run", no_git)
    assert provenance.git_revision() == "unknown"


def test_rows_held_refuse_another_resolution_seed_or_rgb_format_naming_them(tmp_path):
    from dataclasses import replace

    from manifests.writer import write_part
    from manifests.synthetic import episode_table
    from pipeline.planner import make_plan
    from pipeline.provenance import RunConfigError, check_rows
    from pipeline.settings import RunConfig

    storage, config = _tiny_root(tmp_path)
    check_rows(storage, config)  # a paired root's seeds derive from its pairing
    uri, plan = storage.uri, config.plan

    def refused(plan_changes, says):
        with pytest.raises(RunConfigError) as raised:
            check_rows(storage, RunConfig(plan=replace(plan, **plan_changes), world="test"))
        assert str(raised.value) == f"{uri} {says}; frames would not match: use a new --out"

    refused({"width": 32}, "holds frames at 64x36, this run asks for 32x36")
    refused({"seed": 6}, "holds frames made with another run seed than 6 (T01_CN_A episode 0)")
    refused({"rgb_format": "jpg"}, "holds png rgb files, this run asks for jpg")
    spec = replace(make_plan(plan).episodes[0], episode=1, width=32)
    write_part(storage, spec.scenario, spec.episode, episode_table(spec))
    refused({}, "holds frames at 32x36, 64x36, this run asks for 64x36")


def test_a_run_with_another_config_is_refused_in_one_sentence_naming_what_differs(tmp_path):
    from dataclasses import replace

    from pipeline.provenance import RunConfigError, check_before_repair, prepare_root
    from pipeline.settings import RunConfig

    empty, config = _tiny_root(tmp_path / "empty", parts=False)
    storage, _ = _tiny_root(tmp_path / "held")

    def refused(where, plan_changes, says, extend=True):
        other = RunConfig(plan=replace(config.plan, **plan_changes), world="test")
        for check in (prepare_root, check_before_repair):
            with pytest.raises(RunConfigError) as raised:
                check(where, other, extend=extend)
            assert str(raised.value) == f"{where.uri} {says}"

    refused(empty, {"seed": 6, "width": 32}, "holds no frames, but its run.json records a run with another "
            "width, seed (seed 5 -> 6; width 64 -> 32); run that command, or use a new --out (this one holds nothing to keep)")
    refused(storage, {"seed": 6}, "holds frames made with a different seed (seed 5 -> 6); "
            "frames would not match: use a new --out")
    held = ",".join(config.plan.outputs)
    refused(storage, {"outputs": ("rgb",)}, f"holds the outputs {held}; this run asks for rgb: pass --outputs "
            f"{held} to resume it, or use a new --out")
    refused(storage, {"domains": "T01_CN_B"}, "was produced with another config (domains 'T01_CN_A' -> 'T01_CN_B'); "
            "pass --extend to add to it, or use a new --out", extend=False)
    for check in (prepare_root, check_before_repair):
        with pytest.raises(RunConfigError, match="pass --extend"):  # the default: no --extend
            check(storage, RunConfig(plan=replace(config.plan, domains="T01_CN_B"), world="test"))
    check_before_repair(storage, RunConfig(plan=replace(config.plan, domains="T01_CN_B"), world="test"), extend=True)


def test_differences_and_changed_entries_name_what_a_run_changes():
    from pipeline.provenance import _differences, changed_entries

    fg1, fg2 = {"code": "FG1", "fog": 0.5}, {"code": "FG2", "fog": 0.7}
    assert _differences({"seed": 5, "old_key": 1}, {"seed": 6}) == ["seed 5 -> 6"]  # a key only run.json has: not a change
    assert _differences({"catalog": {"weather": [fg1]}, "seed": 5}, {"seed": 5, "catalog": {"weather": [fg1, fg2]}}) == [
        "catalog ['weather FG1'] -> ['weather FG1', 'weather FG2']"]
    assert _differences({"catalog": {"weather": [fg1]}}, {}) == ["catalog ['weather FG1'] -> []"]
    assert changed_entries({"weather": [fg1]}, {"weather": [fg1, fg2]}) == []  # appended: nothing changed
    assert changed_entries({"weather": [fg1, fg2]}, {"weather": [{**fg1, "fog": 0.6}]}) == ["weather 'FG1'", "weather 'FG2'"]
    assert changed_entries({"weather": [fg1]}, None) == changed_entries({"weather": [fg1]}, {"town": []}) == ["weather 'FG1'"]
    assert changed_entries(None, {"weather": [fg1]}) == []


def test_user_domain_entries_may_be_appended_to_but_never_changed(tmp_path):
    from pipeline.provenance import RunConfigError, _refuse_differences
    from storage import Storage

    storage = Storage.from_uri(str(tmp_path))
    fg1, fg2 = {"code": "FG1", "fog": 0.5}, {"code": "FG2", "fog": 0.7}
    _refuse_differences(storage, {"catalog": {"weather": [fg1]}}, {"catalog": {"weather": [fg1, fg2]}}, extend=True)
    with pytest.raises(RunConfigError) as raised:
        _refuse_differences(storage, {"catalog": {"weather": [fg1]}}, {"catalog": {"weather": [{**fg1, "fog": 0.6}]}}, True)
    assert str(raised.value) == (
        f"{storage.uri} was made with other parameters for the domain weather 'FG1' (run.json records them); frames "
        "would not match: resume without --catalog, with the same entries, or use a new --out")


def test_extending_a_root_keeps_its_history_layout_and_deflater(tmp_path):
    """An old root (flat layout, ISA-L frames) extended twice: both runs appended to its
    history, its layout and its PNG deflater kept (one root never mixes two)."""
    from dataclasses import replace

    from manifests.layout import FLAT, LAYOUT_KEY
    from outputs.encoding import encoder_identity
    from pipeline.provenance import _fresh_record, prepare_root, recorded_as_asked
    from pipeline.settings import RunConfig
    from roots.run_file import RUN_FILE, read_record, record_bytes

    storage, config = _tiny_root(tmp_path)
    isal = encoder_identity("png", "isal")
    storage.write_bytes(RUN_FILE, record_bytes(_fresh_record(config.to_dict(), layout=FLAT, encoder=isal)))
    assert recorded_as_asked(storage, config) == read_record(storage)  # ISA-L frames: this run may add to them
    b = RunConfig(plan=replace(config.plan, domains="T01_CN_A,T01_CN_B"), world="test")
    c = RunConfig(plan=replace(config.plan, domains="T01_CN_A,T01_CN_B,T01_CN_C"), world="test")
    prepare_root(storage, b, extend=True)
    record = {**prepare_root(storage, c, extend=True), "checksum": read_record(storage)["checksum"]}
    assert record == read_record(storage)
    assert record["history"] == [config.to_dict(), b.to_dict(), c.to_dict()] and record["config"] == c.to_dict()
    assert record[LAYOUT_KEY] == FLAT and record["encoder"] == isal
    assert recorded_as_asked(storage, b) is None and recorded_as_asked(storage, c) == record


def test_an_encoder_is_recorded_in_an_empty_root_and_refused_beside_frames(tmp_path):
    from outputs.encoding import encoder_identity
    from pipeline.provenance import (UNRECORDED_ENCODER, RunConfigError, check_before_repair, check_encoder,
                                     recorded_as_asked)
    from roots.run_file import RUN_FILE, read_record, record_bytes

    empty, config = _tiny_root(tmp_path / "empty", parts=False)
    old = {k: v for k, v in read_record(empty).items() if k != "encoder"}  # before encoders were recorded
    empty.write_bytes(RUN_FILE, record_bytes(old))
    assert recorded_as_asked(empty, config) is None  # prepare_root decides
    assert check_encoder(empty, old) == read_record(empty) == {**old, "encoder": encoder_identity("png")}
    storage, _ = _tiny_root(tmp_path / "held")
    storage.write_bytes(RUN_FILE, record_bytes(old))
    assert recorded_as_asked(storage, config) is None
    with pytest.raises(RunConfigError) as raised:
        check_encoder(storage, old)
    assert str(raised.value) == (
        f"{storage.uri} holds frames written by another encoder ({UNRECORDED_ENCODER}; this run writes "
        f"{encoder_identity('png')}); one root never mixes encoders, since a re-rendered frame would not match its "
        "files: use a new --out, or the encoder that made the root")
    with pytest.raises(RunConfigError) as raised:
        check_before_repair(storage, config)
    assert str(raised.value) == (
        f"{storage.uri} holds frames written by another encoder ({UNRECORDED_ENCODER}); repair would re-render "
        "them with this one: repair with the encoder that made the root")


def test_a_damaged_run_json_is_rewritten_only_by_a_repair_and_a_lost_one_from_the_rows(tmp_path, caplog):
    from manifests.layout import LAYOUT_KEY, NEW_ROOT_LAYOUT
    from outputs.encoding import encoder_identity
    from pipeline.provenance import RunConfigError, prepare_root
    from roots.run_file import REPAIR_HINT, RUN_FILE, read_record

    storage, config = _tiny_root(tmp_path)
    storage.write_bytes(RUN_FILE, b"{not json")
    with pytest.raises(RunConfigError, match=f"; {REPAIR_HINT}$"):
        prepare_root(storage, config)
    with caplog.at_level("WARNING", logger="pipeline.provenance"):
        record = prepare_root(storage, config, repair=True)
    assert f"rewriting the damaged {storage.join(RUN_FILE)} from this run's options" in caplog.messages
    assert record == read_record(storage) and record["config"] == config.to_dict()
    assert record["encoder"] == encoder_identity("png") and record[LAYOUT_KEY] == NEW_ROOT_LAYOUT
    storage.delete(RUN_FILE)  # lost: made again from this run's options, the rows checked first
    assert prepare_root(storage, config)["config"] == config.to_dict()


def test_a_lost_run_json_of_an_isal_root_is_written_again_with_isal(tmp_path):
    """run.json lost: the record made again names the deflater of the PNG files the
    parts list (an ISA-L root stays ISA-L), not this run's default."""
    import numpy as np

    from manifests.reader import read_part
    from manifests.schema import output_columns
    from outputs.deflaters import deflating_with
    from outputs.encoding import encoder_identity, png_bytes
    from outputs.table import OUTPUTS
    from pipeline.provenance import prepare_root
    from roots.run_file import RUN_FILE

    storage, config = _tiny_root(tmp_path)
    row = read_part(storage, "T01_CN_A", 0).slice(0, 1).to_pylist()[0]
    with deflating_with("isal"):
        png = png_bytes(np.tile(np.arange(64, dtype=np.uint8)[None, :, None], (36, 1, 3)))  # noise: either deflater's
    for name in OUTPUTS:
        if (row[output_columns(name)[0]] or "").endswith(".png"):
            storage.write_bytes(row[output_columns(name)[0]], png)
    storage.delete(RUN_FILE)
    assert prepare_root(storage, config)["encoder"] == encoder_identity("png", "isal")

def test_a_run_json_another_driver_wrote_first_is_the_one_compared(monkeypatch, tmp_path):
    from pipeline.provenance import _fresh_record, prepare_root
    from roots.run_file import RUN_FILE, record_bytes

    storage, config = _tiny_root(tmp_path)
    storage.delete(RUN_FILE)
    theirs = {**_fresh_record(config.to_dict()), "git_revision": "the other driver's"}
    real = storage.create_exclusive

    def second(rel, data):
        assert real(rel, record_bytes(theirs))
        return real(rel, data)

    monkeypatch.setattr(storage, "create_exclusive", second)
    assert prepare_root(storage, config)["git_revision"] == "the other driver's"


def test_root_deflater_and_holds_frames(tmp_path):
    from outputs.encoding import encoder_identity
    from pipeline.provenance import holds_frames, root_deflater

    assert root_deflater({"encoder": encoder_identity("jpg", "isal")}) == "isal"
    assert root_deflater({"encoder": "png-sub-zlib level 9"}) == root_deflater(None) == "zlib-ng"
    storage, _ = _tiny_root(tmp_path, parts=False)
    assert not holds_frames(storage)
    storage.write_bytes("T01_CN_A/e0000/rgb/x.png", b"png")
    assert holds_frames(storage)



def test_specs_for_a_root_take_its_layout_deflater_and_each_scenes_place_in_its_history():
    """A scene's split in a NEW_RULES root follows its place among every selection the
    root's run.json records (an earlier run's scenes first); an older root keeps the plan's."""
    from dataclasses import replace

    from manifests.layout import FLAT, LAYOUT_KEY
    from outputs.encoding import encoder_identity
    from pipeline.planner import make_plan
    from pipeline.provenance import _fresh_record, for_root
    from tests.test_caught_bugs import TINY

    plan = replace(TINY, domains="T01_CN_B")
    specs = make_plan(plan).episodes
    assert [s.split for s in specs] == ["train"]
    earlier = replace(TINY, domains="T02_CN_A,T03_CN_A,T04_CN_A").to_dict()
    record = {**_fresh_record(plan.to_dict(), [earlier], FLAT, encoder_identity("png", "isal")), "config": plan.to_dict()}
    assert [(s.split, s.layout, s.png_deflater) for s in for_root(specs, record)] == [("test", FLAT, "isal")]
    alone = {k: v for k, v in record.items() if k != "history"}  # a record without its history: this run's scenes
    assert [s.split for s in for_root(specs, alone)] == ["train"]
    old_rules = {**record, "config": {**plan.to_dict(), "rules": 0}, LAYOUT_KEY: FLAT}
    assert [s.split for s in for_root(specs, old_rules)] == ["train"]
    from domains.catalog import BUILTIN
    from domains.catalog_file import with_file

    mine = replace(TINY, domains="T09_CN_A",  # a user's town, known only from the root's run.json
                   catalog=with_file(BUILTIN, '[[town]]\ncode = "T09"\nlike = "T01"\n', "mine.toml").layer_json())
    assert [(s.scenario, s.split) for s in for_root(make_plan(mine).episodes, _fresh_record(mine.to_dict()))] == [
        ("T09_CN_A", "train")]

# ------------------------------------------------------------------ exports/export ----


@pytest.mark.parametrize("changes, says", [
    ({"format": "voc"}, "unknown export format 'voc'; valid formats: cityscapes, idda, hf, coco, webdataset"),
    ({"as_split": "dev"}, "unknown split 'dev'; valid splits: "),
    ({"splits": "random"}, "unknown split files 'random'; valid: "),
    ({"splits": "feddrive"}, "split files 'feddrive' are for the idda format, not 'cityscapes'"),
    ({"format": "idda", "holdout": "T01_*_*"}, "a holdout selection needs --splits feddrive"),
    ({"files": "move"}, "unknown file mode 'move'; valid modes: "),
    ({"to": "s3://bucket/export"}, "export target must be a local directory (or s3:// for webdataset), got s3://bucket/export"),
    ({"shard_size": 1 << 20}, "--outputs and --shard-size are for the webdataset format, not 'cityscapes'"),
    ({"format": "webdataset", "shard_size": (1 << 16) - 1}, "shard size must be at least 65,536 bytes, got 65,535"),
    ({"format": "webdataset", "skip_damaged": True}, "--skip-damaged is not available for webdataset"),
    ({"threads": 0}, "threads must be at least 1, got 0"),
])
def test_an_export_config_is_refused_in_one_line_naming_what(changes, says):
    from exports.export import ExportConfig

    with pytest.raises(ValueError) as raised:
        ExportConfig(**{"root": "/data/root", "to": "/data/export", **changes}).validate()
    assert str(raised.value).startswith(says)


@pytest.mark.parametrize("changes", [
    {"format": "idda", "splits": "feddrive", "holdout": "T01_*_*"},
    {"format": "webdataset", "to": "s3://bucket/shards", "shard_size": 1 << 16},
    {"to": "file:///data/export", "as_split": "test", "files": "copy", "threads": 1},
])
def test_an_export_config_within_bounds_is_accepted(changes):
    from exports.export import ExportConfig

    ExportConfig(**{"root": "/data/root", "to": "/data/export", **changes}).validate()


def test_leftovers_of_killed_exports_are_put_back_or_removed_and_a_commit_rechecks_the_tree(monkeypatch, tmp_path, caplog):
    """Beside a target, a killed export's .old (a finished export moved aside) is put back where
    nothing is, its .tmp removed; a live or another host's folder, or a link, is left. A commit
    replaces the export it found only while that still holds the tree it found, then syncs the parent."""
    import socket
    import subprocess
    import uuid

    from exports import export as ex
    from roots.contract import RootError, export_tree

    dead = subprocess.Popen(["true"])
    dead.wait()

    def temp(pid, kind, host=socket.gethostname(), marker=True):
        path = tmp_path / f".exp.idda-export.{host}.{pid}.{uuid.uuid4().hex}.{kind}"
        path.mkdir()
        if marker:
            (path / ex.MARKER).write_text("{}")
        return path

    target = tmp_path / "exp"
    old, killed = temp(dead.pid, "old"), temp(dead.pid, "tmp")
    kept = [temp(os.getpid(), "tmp"), temp(dead.pid, "tmp", host="elsewhere.example")]
    link = tmp_path / f".exp.idda-export.{socket.gethostname()}.{dead.pid}.{uuid.uuid4().hex}.tmp"
    link.symlink_to(kept[0], target_is_directory=True)
    with caplog.at_level("INFO", logger="exports.export"):
        handled = ex.clean_leftovers(str(target))
    assert sorted(handled) == sorted([str(old), str(killed)])
    assert ex.is_complete(str(target)) and not old.exists() and not killed.exists()
    assert all(p.is_dir() for p in kept) and link.is_symlink()
    assert f"put back {target}: an export killed while replacing it had moved it to {old}" in caplog.messages
    assert f"removed {killed}, left by a killed export" in caplog.messages

    synced = []
    monkeypatch.setattr(ex, "sync_dir", synced.append)
    found = export_tree(str(target))
    (target / "frames.csv").write_text("added meanwhile")
    new = temp(os.getpid(), "tmp")
    with pytest.raises(RootError, match=f"^export target {target} changed while exporting; nothing was replaced$"):
        ex._commit(str(new), str(target), found)
    assert (target / "frames.csv").exists() and new.is_dir() and synced == []
    ex._commit(str(new), str(target), export_tree(str(target)))
    assert not (target / "frames.csv").exists() and ex.is_complete(str(target)) and synced == [str(tmp_path)]
    assert sorted(os.listdir(tmp_path)) == sorted(["exp", link.name, *(p.name for p in kept)])
    empty = tmp_path / "empty"
    empty.mkdir()
    ex._commit(str(temp(os.getpid(), "tmp")), str(empty), None)
    assert ex.is_complete(str(empty)) and synced == [str(tmp_path)] * 2


def test_an_exports_marker_and_report_count_its_frames_per_split_and_record_its_query(monkeypatch, tmp_path_factory, tmp_path):
    """EXPORT.json and the report say what was exported: the query asked, the frames per
    split (all in --as-split's), the file mode, none skipped."""
    import json
    from dataclasses import asdict

    from exports import export as ex
    from manifests.query import SPLITS, Query
    from tests.test_export import TINY_FRAMES, make_tiny_root

    root = make_tiny_root(tmp_path_factory)  # shared with tests/test_export.py
    query = Query(domains="T07_*_*")
    report = ex.export(ex.ExportConfig(root=str(root), to=str(tmp_path / "exp"), format="idda", query=query,
                                       as_split="test", files="copy"))
    per_split = {s: TINY_FRAMES if s == "test" else 0 for s in SPLITS}
    assert report.frames == TINY_FRAMES and report.per_split == per_split and report.skipped == 0
    marker = json.loads((tmp_path / "exp" / ex.MARKER).read_text())
    assert marker["query"] == json.loads(json.dumps(asdict(query))) and marker["per_split"] == per_split and marker["as_split"] == "test"
    assert marker["file_mode"] == "copy" and marker["per_scenario"] == {"T07_HRN_A": TINY_FRAMES}
    rows = (tmp_path / "exp" / ex.INDEX).read_text().splitlines()[1:]
    assert len(rows) == TINY_FRAMES and all(",test," in row for row in rows)


    def no_sync(path):
        raise OSError(5, "disk gone")

    monkeypatch.setattr(ex, "sync_dir", no_sync)  # fails once the export is in place
    with pytest.raises(OSError, match="disk gone"):  # its own error, not the clean-up's
        ex.export(ex.ExportConfig(root=str(root), to=str(tmp_path / "exp2"), format="idda", query=query))


def test_skip_damaged_leaves_out_each_damaged_frame_and_names_every_damaged_file(tmp_path_factory, tmp_path):
    """--skip-damaged: a frame with a damaged file is left out and counted, every damaged file
    named in the report, whichever round of the build found it; a choice of damaged frames only
    is refused naming the first."""
    import shutil

    from exports import export as ex
    from exports.shared import DamagedFile
    from manifests.query import Query
    from tests.test_export import TINY_FRAMES, make_tiny_root

    root = tmp_path / "root"
    shutil.copytree(make_tiny_root(tmp_path_factory), root)
    damaged = sorted(next(root.glob(f"{s}/e0000/rgb/0000_00{i}_*.png")).relative_to(root).as_posix()
                     for s in ("T01_CS_A", "T07_HRN_A") for i in range(TINY_FRAMES))
    for rel in damaged:
        (root / rel).write_bytes(b"")
    report = ex.export(ex.ExportConfig(root=str(root), to=str(tmp_path / "exp"), format="idda", threads=1,
                                       skip_damaged=True))
    assert report.damaged == damaged and report.skipped == len(damaged) and report.frames == report.held - len(damaged)
    with pytest.raises(DamagedFile) as raised:
        ex.export(ex.ExportConfig(root=str(root), to=str(tmp_path / "none"), format="idda", threads=1,
                                  skip_damaged=True, query=Query(domains="T07_*_*")))
    assert str(raised.value).startswith(f"{root}: {damaged[2]} is damaged (as are files of every other frame chosen: 2 damaged)")
    assert not (tmp_path / "none").exists()


# ---------------------------------------------------------------- manifests/reader ----


def _episodes(storage, domains="T01_CN_A", episodes=(0,), frames=3):
    """Synthetic parts (rows only: the files they list do not exist) of ``episodes`` of each scenario."""
    import dataclasses

    from manifests.synthetic import episode_table
    from manifests.writer import write_part
    from pipeline.planner import make_plan
    from tests.test_caught_bugs import TINY

    specs = [dataclasses.replace(spec, episode=e)
             for spec in make_plan(dataclasses.replace(TINY, domains=domains, frames_per_scenario=frames)).episodes
             for e in episodes]
    for spec in specs:
        write_part(storage, spec.scenario, spec.episode, episode_table(spec))
    return specs


def test_misfiled_parts_count_no_frames_are_refused_naming_them_and_never_indexed(tmp_path, caplog):
    """Parts whose rows name another episode (copied over four episodes' parts) hold no frames
    of theirs: episode_frames counts 0, refuse_misfiled names the first three "and 1 more",
    compaction warns and writes no index; a part filed in another scenario's folder is warned about."""
    from manifests.reader import compact, episode_frames, part_summaries, read_manifest, refuse_misfiled
    from manifests.part_file import MisfiledParts
    from manifests.schema import index_path, part_path
    from storage import Storage

    storage = Storage.from_uri(str(tmp_path))
    [spec, *_] = _episodes(storage, episodes=range(5))
    s = spec.scenario
    good = storage.read_bytes(part_path(s, 0, 3))
    for e in range(1, 5):
        storage.write_bytes(part_path(s, e, 3), good)
    summaries = part_summaries(storage)
    assert episode_frames(storage, summaries) == {(s, 0): 3, **{(s, e): 0 for e in range(1, 5)}}
    with pytest.raises(MisfiledParts) as refused:
        refuse_misfiled(storage, summaries)
    assert (f"4 manifest part(s) hold the rows of another scenario or episode "
            f"({s}_e0001, {s}_e0002, {s}_e0003 and 1 more)") in str(refused.value)
    with pytest.raises(MisfiledParts, match=f"{s}_e0001_n3.parquet holds the rows of another scenario or episode"):
        read_manifest(storage)
    with caplog.at_level("WARNING", logger="manifests.reader"):
        assert compact(storage) == []
    assert not storage.exists(index_path(s))
    assert f"{storage.join(part_path(s, 1, 3))} holds the rows of another scenario or episode: {s} not indexed" in caplog.messages

    misfiled = part_path("T02_CN_A", 0).rpartition("/")[0] + "/" + part_path(s, 0, 3).rpartition("/")[2]
    storage.write_bytes(misfiled, good)
    caplog.clear()
    with caplog.at_level("WARNING", logger="manifests.reader"):
        part_summaries(storage)
    assert (f"{storage.join(misfiled)} is filed under another scenario's folder: not read (`idda verify` names it)"
            in caplog.messages)


def test_compact_folds_only_the_scenarios_asked_and_the_manifest_reads_sorted(tmp_path):
    """compact(root, [scenario]) writes that scenario's index alone (its episodes in its footer, no
    rig columns in a default-rig root's); the manifest then reads one scenario from its index and
    the other from its parts, still sorted by scenario, episode, frame. A new part makes the index
    stale, and the next compaction folds in the new part alone (the rows of the others from the index)."""
    import pyarrow.compute as pc
    import pyarrow.parquet as pq

    from manifests.reader import compact, index_episodes, manifest_files, read_manifest
    from manifests.schema import RIG_FIELDS, index_path, part_path
    from storage import Storage

    storage = Storage.from_uri(str(tmp_path))
    specs = _episodes(storage, domains="T01_CN_A,T02_CN_A", episodes=(0, 1))
    first, second = sorted({spec.scenario for spec in specs})
    stale = tmp_path / "_index" / f".{first}.parquet.{'0' * 32}.tmp"  # a compaction killed mid-write left it
    stale.parent.mkdir()
    stale.write_bytes(b"half")
    assert compact(storage, [first]) == [first]
    assert not stale.exists()  # the dataset then lists the second's parts before the first's index
    assert storage.exists(index_path(first)) and not storage.exists(index_path(second))
    assert manifest_files(storage) == [index_path(first), *(part_path(second, e, 3) for e in (0, 1))]
    table = read_manifest(storage)
    keys = list(zip(*(table.column(k).to_pylist() for k in ("scenario", "episode", "frame"))))
    assert keys == sorted(keys) and len(keys) == 12 and {k[0] for k in keys} == {first, second}
    assert index_episodes(storage, index_path(first)) == {0, 1}
    assert not {name for name, _ in RIG_FIELDS} & set(pq.read_schema(str(tmp_path / index_path(first))).names)
    _episodes(storage, domains=first, episodes=(2,))  # the index is stale now: its parts are read
    assert manifest_files(storage)[:3] == [part_path(first, e, 3) for e in (0, 1, 2)]
    held = tmp_path / part_path(first, 0, 3)
    held.write_bytes(bytes(held.stat().st_size))  # the index holds its rows: an incremental fold never reads it
    assert compact(storage, [first]) == [first]
    assert index_episodes(storage, index_path(first)) == {0, 1, 2}
    assert len(read_manifest(storage, filter=pc.field("scenario") == first)) == 9


def test_an_episodes_parts_are_listed_the_one_readers_use_first_and_both_kept_if_it_lies(tmp_path, caplog):
    """Beside an old name, the counted name is listed first (readers use it); where the counted
    name says more rows than it holds, compaction keeps both and names them in its warning."""
    from manifests.reader import compact, episode_frames, episode_parts
    from manifests.schema import index_path, part_path
    from storage import Storage

    storage = Storage.from_uri(str(tmp_path))
    [spec] = _episodes(storage)
    s, e = spec.scenario, spec.episode
    data = storage.read_bytes(part_path(s, e, 3))
    storage.write_bytes(part_path(s, e), data)
    assert episode_parts(storage, s, e) == [part_path(s, e, 3), part_path(s, e)]
    compact(storage)  # the old name no reader uses is removed
    assert not storage.exists(part_path(s, e)) and storage.exists(part_path(s, e, 3))
    storage.write_bytes(part_path(s, e), data)
    storage.delete(part_path(s, e, 3))
    storage.delete(index_path(s))
    assert episode_frames(storage) == {(s, e): 3}  # an old name alone: its rows read from its footer
    storage.write_bytes(part_path(s, e), data[: len(data) // 2])
    assert episode_frames(storage) == {(s, e): 0}  # torn: none
    storage.write_bytes(part_path(s, e), data)
    storage.write_bytes(part_path(s, e, 4), data)  # says 4 rows, holds 3
    with caplog.at_level("WARNING", logger="manifests.reader"):
        compact(storage)
    assert storage.exists(part_path(s, e)) and storage.exists(part_path(s, e, 4))
    assert (f"{storage.join(part_path(s, e))} and {storage.join(part_path(s, e, 4))} name the same episode"
            in caplog.text)


def test_a_part_written_without_statistics_is_summarised_from_its_columns(tmp_path):
    """A part whose footer has no statistics is read for its few columns: its summary
    still says its rows and bytes (not unreadable, so its episode is done)."""
    import pyarrow.parquet as pq

    from manifests.reader import part_summaries, read_part
    from manifests.schema import part_path
    from storage import Storage

    storage = Storage.from_uri(str(tmp_path))
    [spec] = _episodes(storage)
    rel = part_path(spec.scenario, spec.episode, 3)
    [summary] = part_summaries(storage).values()
    assert summary.rows == 3 and summary.size == (tmp_path / rel).stat().st_size
    table = read_part(storage, spec.scenario, spec.episode)
    pq.write_table(table, str(tmp_path / rel), write_statistics=False)
    [summary] = part_summaries(storage).values()
    assert summary is not None and summary.rows == 3 and summary.size == (tmp_path / rel).stat().st_size


def test_a_damaged_index_is_skipped_with_its_error_named_and_its_parts_read(tmp_path, caplog):
    """An index torn after compaction: the manifest is read from its parts, and the
    warning names the index and why it was not read."""
    from manifests.reader import compact, read_manifest
    from manifests.schema import index_path
    from storage import Storage

    storage = Storage.from_uri(str(tmp_path))
    [spec] = _episodes(storage, episodes=(0, 1))[:1]
    assert compact(storage) == [spec.scenario]
    rel = index_path(spec.scenario)
    data = storage.read_bytes(rel)
    storage.write_bytes(rel, data[:40] + bytes(b ^ 0xFF for b in data[40:60]) + data[60:])  # a page; the footer whole
    with caplog.at_level("WARNING", logger="manifests.reader"):
        assert len(read_manifest(storage)) == 6
    [message] = [m for m in caplog.messages if m.startswith("ignoring the damaged index")]
    assert message.startswith(f"ignoring the damaged index {storage.join(rel)} (manifest file {storage.join(rel)} is unreadable: ")


# ------------------------------------------------------------------ roots/contract ----


def test_roots_old_and_new_are_told_apart_from_other_folders(tmp_path):
    """A root made before the marker (run.json and a manifest part) is ours, and so is a folder
    with a manifest part alone for the commands that read one; a folder of other files is
    refused by claim_root naming what it holds."""
    from roots.contract import RootError, claim_root, is_our_root, own_top_names, require_root
    from storage import Storage

    old = Storage.from_uri(str(tmp_path / "old"))
    old.write_bytes("manifest/town=T01/weather=CN/viewpoint=A/T01_CN_A_e0000_n3.parquet", b"part")
    require_root(old)  # a manifest part alone
    assert not is_our_root(old)
    old.write_bytes("run.json", b"{}")
    assert is_our_root(old)
    claim_root(old)
    assert not old.exists("idda-root.json")  # an old root stays as it was
    new = Storage.from_uri(str(tmp_path / "new"))
    claim_root(new)
    require_root(new)  # its marker alone: a root before its run.json
    assert own_top_names(["T01_CN_A"]) >= {"idda-root.json", "run.json", "manifest", "T01_CN_A"}
    with pytest.raises(RootError, match=f"is inside the output root {tmp_path / 'new'}; use a directory outside"):
        claim_root(Storage.from_uri(str(tmp_path / "new" / "inner")))
    other = Storage.from_uri(str(tmp_path / "other"))
    other.write_bytes("notes.txt", b"mine")
    with pytest.raises(RootError) as refused:
        claim_root(other)
    assert str(refused.value) == (f"{other.uri} is not empty (notes.txt) and is not an idda output root "
                                  "(no idda-root.json); use a new or empty directory as --out")


def test_an_export_target_holding_an_old_root_deep_down_is_refused_naming_it(tmp_path):
    """An old root (run.json beside manifest/, no marker) two folders down a target: the
    target is refused, the message naming that root's folder, not the first folder met."""
    from roots.contract import RootError, check_export_target

    target = tmp_path / "target"
    (target / "a" / "0plain").mkdir(parents=True)
    (target / "a" / "old" / "manifest").mkdir(parents=True)
    (target / "a" / "old" / "run.json").write_text("{}")
    with pytest.raises(RootError) as refused:
        check_export_target(str(target), force=True)
    assert str(refused.value) == f"export target {target} holds the output root {target}/a/old; export elsewhere"
    with pytest.raises(RootError, match="is an output root"):
        check_export_target(str(target / "a" / "old"), force=True)


def test_an_export_marker_that_lists_no_tree_or_a_changed_one_is_refused_saying_why(tmp_path):
    """--force replaces an export only where EXPORT.json records its tree (a dict of entries,
    sha256 and top), and only while the tree is what it records: a file more under a
    recorded folder is a change, counted."""
    import json

    from roots.contract import RootError, check_export_target, export_tree

    target = tmp_path / "export"
    (target / "images").mkdir(parents=True)
    (target / "images" / "a.png").write_bytes(b"png")
    (target / "EXPORT.json").write_text(json.dumps({"tree": ["entries", "sha256", "top"]}))
    with pytest.raises(RootError, match="its EXPORT.json does not list what it wrote"):
        check_export_target(str(target), force=True)
    (target / "EXPORT.json").write_text(json.dumps({"tree": export_tree(str(target))}))
    check_export_target(str(target), force=True)
    (target / "images" / "b.png").write_bytes(b"png")
    with pytest.raises(RootError) as refused:
        check_export_target(str(target), force=True)
    assert "its content changed since the export (3 entries, the export wrote 2);" in str(refused.value)


def test_require_outputs_names_the_missing_output_how_many_frames_lack_it_and_what_all_have(tmp_path):
    """require_outputs passes a table whose every row has the outputs asked, and refuses in one
    line naming the output missing, for how many of how many frames, and those every frame has."""
    import pyarrow as pa

    from manifests.reader import read_part, require_outputs
    from storage import Storage

    storage = Storage.from_uri(str(tmp_path))
    [spec] = _episodes(storage)
    table = read_part(storage, spec.scenario, spec.episode)
    require_outputs(table, ["rgb", "flow"], "the root")
    column = table.schema.get_field_index("flow_path")
    table = table.set_column(column, "flow_path", pa.array(["f.png", None, None], pa.string()))
    with pytest.raises(ValueError) as refused:
        require_outputs(table, ["rgb", "flow"], "the root")
    message = str(refused.value)
    assert message.startswith("the root does not hold the 'flow' output for 2 of 3 frames (every frame has: rgb, depth_raw, ")
    assert message.endswith("); produce it with `idda produce --outputs` into a new root")
    assert "flow" not in message.split("every frame has: ")[1]


# ------------------------------------------------------------------ roots/verify ----


def _verify_root(tiny_root, tmp_path):
    """A copy of the tiny rendered root, its part's path and its frame files (sorted)."""
    from tests.roots import part_of

    root, storage = _copy_of(tiny_root, tmp_path)
    frames = sorted(str(p.relative_to(root)) for p in (root / "T01_CN_A").rglob("*") if p.is_file())
    return root, storage, part_of(storage, "T01_CN_A", 0), frames


def test_verify_names_each_damaged_stray_or_linked_file_whole_in_a_fixed_order(tiny_root, tmp_path):
    """Every problem verify finds carries its kind, path, scenario, episode and detail (repair
    re-renders the episodes of missing, corrupt and bad-part problems, never of an extra
    file), in the same order whatever order they were found in; hidden files are never
    listed, other names are foreign, links are named and never followed."""
    import os

    from manifests.schema import part_path
    from roots.verify import LINK_DETAIL, Problem, VerifyProgress, verify

    root, storage, part, frames = _verify_root(tiny_root, tmp_path)
    short, flipped, folder, gone = frames[0], frames[1], frames[2], frames[3]
    os.unlink(root / gone)
    size = os.path.getsize(root / short)
    (root / short).write_bytes((root / short).read_bytes()[:-4])  # a size the listing tells
    data = bytearray((root / flipped).read_bytes())
    data[-1] ^= 1
    (root / flipped).write_bytes(bytes(data))  # the same size: only its hash tells
    folder_size = os.path.getsize(root / folder)
    os.unlink(root / folder)
    (root / folder).mkdir()  # a folder in a frame file's place
    stray = "T01_CN_A/e0009/rgb/0009_000_T01_CN_A.png"  # ours by name, listed by no part
    (root / stray).parent.mkdir(parents=True)
    (root / stray).write_bytes(b"stray")
    (root / "T01_CN_A" / ".tmp-in-flight").write_bytes(b"x")  # hidden: never listed
    (root / "T01_CN_A" / "notes.txt").write_bytes(b"x")  # not of our names: foreign
    os.symlink("/nonexistent", root / "T01_CN_A" / "elsewhere")
    os.makedirs(root / part_path("T01_CN_A", 7, 3))  # a folder named as a part
    os.symlink("/nonexistent", root / "manifest" / "linked.parquet")
    (root / "manifest" / "README").write_bytes(b"x")
    (root / "manifest" / ".DS_Store").write_bytes(b"x")
    misfiled = part_path("T02_CN_A", 0).rpartition("/")[0] + "/" + part.rpartition("/")[2]
    os.makedirs((root / misfiled).parent)
    (root / misfiled).write_bytes((root / part).read_bytes())
    seen = []

    report = verify(root, progress=seen.append)
    folder_error = [p.detail for p in report.problems if p.path == folder]
    assert report.problems == [
        Problem("link", "manifest/linked.parquet", None, None, LINK_DETAIL),  # (no scenario sorts first)
        Problem("link", "T01_CN_A/elsewhere", "T01_CN_A", None, LINK_DETAIL),
        Problem("bad-part", part_path("T01_CN_A", 7, 3), "T01_CN_A", 7, "a folder where a part file goes"),
        Problem("missing", gone, "T01_CN_A", 0),
        Problem("corrupt", short, "T01_CN_A", 0, f"{size - 4} bytes, expected {size}"),
        Problem("corrupt", flipped, "T01_CN_A", 0, f"{len(data)} bytes, expected {len(data)}"),
        Problem("corrupt", folder, "T01_CN_A", 0, folder_error[0]),
        Problem("extra", misfiled, None, None, "a part filed under another scenario's folder"),
        Problem("extra", stray, "T01_CN_A", 9, "not in the manifest"),
    ]
    assert folder_error[0] and folder_size
    assert report.counts() == {"link": 2, "bad-part": 1, "missing": 1, "corrupt": 3, "extra": 2}
    assert report.affected_episodes() == {("T01_CN_A", 0), ("T01_CN_A", 7)}
    assert report.foreign == ["T01_CN_A/notes.txt", "manifest/README"]
    assert report.episodes_checked == 1 and report.files_checked == len(frames)
    assert report.bytes_checked == sum(os.path.getsize(root / f) for f in frames if f not in (short, flipped, folder, gone))
    assert seen[0] == VerifyProgress(0, 1, 0, seen[0].elapsed_s)
    assert [(p.episodes_done, p.files_done) for p in seen[1:]] == [(0, len(frames)), (1, len(frames))]


def _bad(report, kinds=("bad-part", "bad-index", "bad-run")) -> list:
    return [p for p in report.problems if p.kind in kinds]


def test_verify_names_a_damaged_part_or_index_and_accepts_one_written_the_old_way(monkeypatch, tiny_root, tmp_path):
    """A part that is not Parquet, or whose bytes are not its rows as this pyarrow writes them,
    is a bad part of its episode; one written as parts were before (plain lists, Arrow schema
    stored), or by another writer, is sound. An index unreadable, unreadable at all, of a
    scenario without parts, or not the index its parts rebuild is a bad index."""
    import io

    import pyarrow.parquet as pq

    from manifests.part_file import read_part_file
    from manifests.schema import PART_SCHEMA, as_plain_lists, index_path, part_path
    from manifests.writer import part_bytes
    from roots import verify as verify_module
    from roots.verify import Problem, verify
    from storage import Storage

    root, storage, part, _ = _verify_root(tiny_root, tmp_path)
    index = index_path("T01_CN_A")
    sound, table = storage.read_bytes(part), read_part_file(storage, part, PART_SCHEMA)
    storage.write_bytes(part, part_bytes(as_plain_lists(table), store_schema=True))  # as parts were written before
    assert verify(root).ok
    snappy = io.BytesIO()
    pq.write_table(table, snappy, compression="snappy")
    storage.write_bytes(part, snappy.getvalue())
    [problem] = _bad(verify(root))  # (the index, built from the sound part's size, is now stale)
    assert problem == Problem("bad-part", part, "T01_CN_A", 0,
                              "its bytes differ from its own rows re-encoded (damaged metadata)")
    monkeypatch.setattr(verify_module, "_this_writer", lambda: "another writer")
    assert _bad(verify(root)) == []  # bytes of another writer are not ours to re-encode
    monkeypatch.undo()
    storage.write_bytes(part, b"not parquet")
    [problem] = _bad(verify(root))
    assert (problem.kind, problem.path, problem.scenario, problem.episode) == ("bad-part", part, "T01_CN_A", 0)
    assert part in problem.detail
    old_name = part_path("T01_CN_A", 0)  # a second name of the episode beside the damaged one: both named
    storage.write_bytes(old_name, sound)
    assert _bad(verify(root)) == [Problem("bad-part", old_name, "T01_CN_A", 0,
                                          f"a second part of this episode, beside the damaged {part}"), problem]
    storage.delete(old_name)

    lying = part_path("T01_CN_A", 0, 5)  # a name that says 5 rows, 3 held
    storage.write_bytes(lying, sound)
    storage.delete(part)
    assert _bad(verify(root)) == [Problem("bad-part", lying, "T01_CN_A", 0, "its name says 5 rows, it holds 3")]
    storage.delete(lying)
    storage.write_bytes(part, sound)
    stored = storage.read_bytes(index)
    rewritten = io.BytesIO()
    pq.write_table(pq.read_table(io.BytesIO(stored)), rewritten, compression="snappy")  # its footer's records kept
    storage.write_bytes(index, rewritten.getvalue())
    assert _bad(verify(root)) == [Problem("bad-index", index, "T01_CN_A", None, "differs from the index rebuilt from its parts")]
    storage.write_bytes(index, b"not parquet")
    assert _bad(verify(root)) == [Problem("bad-index", index, "T01_CN_A", None, "unreadable footer")]
    storage.write_bytes(index, stored)
    real = Storage.read_bytes

    def failing(self, rel):
        if rel == index:
            raise OSError("disk error")
        return real(self, rel)

    monkeypatch.setattr(Storage, "read_bytes", failing)
    assert _bad(verify(root)) == [Problem("bad-index", index, "T01_CN_A", None, "disk error")]
    monkeypatch.undo()
    storage.delete(part)
    assert _bad(verify(root)) == [Problem("bad-index", index, "T01_CN_A", None, "its scenario has no parts")]


def test_verify_reads_run_json_and_the_live_producers_and_times_its_first_hash(monkeypatch, tiny_root, tmp_path):
    """A damaged run.json is a bad run naming why, a lost one beside parts is "missing"; the
    layout run.json records decides which files are ours (a flat-named file in a root of
    episode folders is foreign, even with no part left to tell); frames without a part
    beside a live producer are in progress, not extra; the first hash is timed from the start."""
    import time as real_time

    from roots import verify as verify_module
    from roots.lease import register_producer
    from roots.run_file import RunRecordError, read_record
    from manifests.schema import RUN_FILE, index_path
    from roots.verify import Problem, verify

    root, storage, part, frames = _verify_root(tiny_root, tmp_path)

    class Clock:  # wall-clock time stands still: the first hash is 0 s from the start
        perf_counter = staticmethod(real_time.perf_counter)

        @staticmethod
        def time():
            return 1000.0

    monkeypatch.setattr(verify_module, "time", Clock)
    report = verify(root)
    assert report.ok and report.first_hash_s == 0.0 and report.episodes_checked == 1
    monkeypatch.undo()

    record = storage.read_bytes(RUN_FILE)
    storage.write_bytes(RUN_FILE, b"{damaged")
    with pytest.raises(RunRecordError) as damaged:
        read_record(storage)
    assert verify(root).problems == [Problem("bad-run", RUN_FILE, None, None, str(damaged.value))]
    storage.delete(RUN_FILE)
    assert verify(root).problems == [Problem("bad-run", RUN_FILE, None, None, "missing")]

    storage.write_bytes(RUN_FILE, record)
    storage.delete(part)
    storage.delete(index_path("T01_CN_A"))
    flat = "T01_CN_A/rgb/0009_000_T01_CN_A.png"  # the flat layout's name: not this root's
    storage.write_bytes(flat, b"x")
    report = verify(root)
    assert report.foreign == [flat]
    assert sorted(p.path for p in report.problems) == frames and {p.kind for p in report.problems} == {"extra"}
    producer = register_producer(storage, owner="another")
    try:
        report = verify(root)
    finally:
        producer.release()
    assert report.ok and report.in_progress == {("T01_CN_A", 0)} and report.foreign == [flat]
    assert verify(root).in_progress == set()


def test_part_problem_and_config_conflict_name_why_rows_do_not_belong(tmp_path):
    """A part's rows must be of its episode, numbered 0.., one seed and size, paths of the
    layout in the run's rgb format, frame-major in a rig's sensor order; a sensor's size is
    its own where the run's rig gives it one, and the seed derives with the run's pairing."""
    import json

    import pyarrow as pa

    from domains.catalog import scenario as lookup_scenario, using
    from manifests.layout import EPISODE_DIRS, FLAT, frame_path
    from manifests.reader import read_part
    from outputs.table import OUTPUTS
    from manifests.schema import output_columns
    from roots.episode_spec import PAIRED, episode_seed
    from roots.verify import config_conflict, part_problem
    from storage import Storage

    storage = Storage.from_uri(str(tmp_path))
    [spec] = _episodes(storage)
    table = read_part(storage, spec.scenario, 0)
    config = {"seed": 5, "width": table["width"][0].as_py(), "height": table["height"][0].as_py()}

    def changed(name, values):
        return table.set_column(table.schema.get_field_index(name), name, pa.array(values, table.schema.field(name).type))

    assert part_problem(table, spec.scenario, 0, None) is None
    assert part_problem(changed("episode", [1, 1, 1]), spec.scenario, 0, None) == "rows of another scenario or episode"
    assert part_problem(changed("frame", [1, 2, 3]), spec.scenario, 0, None) == "frames are not numbered 0..2"
    assert part_problem(changed("seed", [5, 5, 6]), spec.scenario, 0, None) == "mixed seeds or resolutions"
    assert part_problem(table, spec.scenario, 0, {**config, "seed": spec.seed - 1}) is not None
    assert part_problem(table, spec.scenario, 0, {**config, "seed": 5, "rgb_format": "jpg"}) \
        == "rgb paths do not follow the layout"  # run.json's format, not any format

    stereo = table.take([i // 2 for i in range(6)])  # a stereo rig's part: left, right, frame by frame
    sensors = ["left", "right"] * 3
    stereo = stereo.set_column(stereo.schema.get_field_index("sensor"), "sensor", pa.array(sensors, pa.string()))
    for output in OUTPUTS:
        column = output_columns(output)[0]
        paths = stereo.column(column).to_pylist()
        if paths != [None] * 6:
            paths = [frame_path(spec.scenario, output, f, "png", EPISODE_DIRS, s)
                     for f, s in zip(stereo["frame_id"].to_pylist(), sensors)]
            stereo = stereo.set_column(stereo.schema.get_field_index(column), column, pa.array(paths, pa.string()))
    assert part_problem(stereo, spec.scenario, 0, None) is None
    assert part_problem(stereo, spec.scenario, 0, None, (FLAT,)) == "rgb paths do not follow the layout"  # no crash
    assert part_problem(stereo.take([1, 0, 2, 3, 4, 5]), spec.scenario, 0, None) \
        == "sensor rows are not in the rig's order, frame by frame"
    rgb = stereo.schema.get_field_index(output_columns("rgb")[0])
    without = stereo.set_column(rgb, output_columns("rgb")[0],  # a sensor without an output (a LiDAR has no rgb)
                                pa.array([p if s == "left" else None for p, s in zip(stereo.column(rgb).to_pylist(), sensors)]))
    assert part_problem(without, spec.scenario, 0, None) is None

    seed = episode_seed(5, lookup_scenario(spec.scenario), 0, PAIRED)
    paired = {**config, "pairing": PAIRED}
    assert config_conflict({None: (config["width"], config["height"])}, seed, spec.scenario, 0, paired) is None
    assert config_conflict({None: (config["width"], config["height"])}, seed, spec.scenario, 0, config) \
        == "episode seed does not derive from run.json's seed 5"
    catalog = {"weather": [{"code": "FG1", "like": "CN", "name": "fog one", "fog": 0.5}]}  # a user's weather
    with using(catalog):
        fog_seed = episode_seed(5, lookup_scenario("T01_FG1_A"), 0, PAIRED)
    assert config_conflict({None: (config["width"], config["height"])}, fog_seed, "T01_FG1_A", 0,
                           {**paired, "catalog": catalog}) is None  # known from run.json alone
    rig = json.dumps({"name": "wide", "sensor": [{"name": "front", "kind": "camera"},
                                                   {"name": "side", "kind": "camera", "width": 96, "height": 48}]})
    own = {**paired, "rig": rig}
    assert config_conflict({"front": (config["width"], config["height"]), "side": (96, 48)}, seed, spec.scenario, 0, own) is None
    assert config_conflict({"side": (config["width"], config["height"])}, seed, spec.scenario, 0, own) \
        == f"side frames are {config['width']}x{config['height']}, run.json says 96x48"


def test_since_takes_an_age_or_an_iso_time_utc_unless_it_names_a_zone():
    from roots.verify import parse_since

    assert [parse_since(t, now=100000.0) for t in ("90s", " 30m ", "2h", "1.5d")] == [99910.0, 98200.0, 92800.0, -29600.0]
    assert parse_since("2026-11-25T13:00") == 1795611600.0
    assert parse_since("2026-11-25T13:00+01:00") == 1795611600.0 - 3600
    with pytest.raises(ValueError, match=r"^--since '3w' is neither an age \(90s, 30m, 2h, 3d\) nor an ISO time \(2026-11-25T13:00\)$"):
        parse_since("3w")


def test_verify_of_a_remote_root_finds_a_file_gone_from_its_listing_without_a_request(tiny_root, tmp_path):
    """On S3 a file the scenario's listing lacks is missing (of its episode, so repair renders it
    again) without a request; the files listed are read with the listing's size, once each."""
    from manifests.layout import EPISODE_DIRS
    from roots.run_file import read_record
    from roots.verify import Problem, Scope, VerifyReport, check_unit, plan_units

    root, storage, _, frames = _verify_root(tiny_root, tmp_path)
    storage.delete(frames[0])
    reads = []

    class Remote:  # the root as S3 shows it: listed, then read by path
        is_local = False

        def __getattr__(self, name):
            return getattr(storage, name)

        def read_listed(self, rel, size):
            reads.append(rel)
            return storage.read_listed(rel, size)

    [unit] = plan_units(storage, Scope(), VerifyReport(), False, (EPISODE_DIRS,))
    result = check_unit(Remote(), unit, read_record(storage)["config"])
    assert result.problems == [Problem("missing", frames[0], "T01_CN_A", 0)]
    assert sorted(reads) == frames[1:] and result.files_checked == len(frames)
