"""Provenance and config guard for an output root (``<root>/run.json``).

The file records the run config (with the user domain entries in force, so
the root is resumed, extended and verified without the domain file), package
versions, the git revision, the file encoder
(``outputs.encoding.encoder_identity``) and the root's file layout
(``manifests.layout``: a new root's, kept for the root's life). A later run into the
same root must ask for the same config, or pass --extend; settings that decide
what a frame looks like (seed, resolution, world) can never change within one
root, since frames would no longer match each other. Nor can the encoder once
the root holds frames: another encoder (or version) writes other bytes for the
same image, so a resumed episode would not match the one it replaces.
"""

from __future__ import annotations

import logging
import os
import platform
import subprocess
from importlib import metadata
from pathlib import Path

from domains.catalog import scenario as lookup_scenario, using
from domains.catalog_file import current_layer
from domains.rigs import rig_named
from manifests.layout import LAYOUT_KEY, NEW_ROOT_LAYOUT, held_layout, record_layout
from manifests.part_file import ManifestError, read_part_file
from manifests.reader import done_episodes, part_summaries
from manifests.schema import MANIFEST_DIR, NEW_RULES, PART_SCHEMA, RUN_FILE, output_columns
from outputs.deflaters import DEFAULT_DEFLATER, deflater_named_by, deflater_of_files, deflaters_of_png
from outputs.encoding import PHOTO_OUTPUTS, encoder_identity
from outputs.table import OUTPUTS
from pipeline.planner import scene_places, scene_split
from pipeline.settings import CONFIG_SHAPE, FRAME_DEFINING, PlanConfig, RunConfig, recorded
from roots.contract import own_top_names, root_entries
from roots.episode_spec import episode_seed
from roots.run_file import REPAIR_HINT, RunRecordError, read_record, record_bytes
from storage import StorageError


_PACKAGES = ("idda-pipeline", "numpy", "pyrender", "PyOpenGL", "trimesh", "ray", "pyarrow", "opencv-python-headless")


log = logging.getLogger(__name__)


class RunConfigError(Exception):
    """The output root was produced with a different config."""


def package_versions() -> dict[str, str]:
    versions = {"python": platform.python_version()}
    for name in _PACKAGES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = "not installed"
    return versions


def git_revision() -> str:
    here = Path(__file__).resolve().parent
    try:
        out = subprocess.run(
            ["git", "rev-parse", "HEAD"], cwd=here, capture_output=True, text=True, timeout=10, check=True
        )
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"], cwd=here, capture_output=True, text=True, timeout=10
        )
        return out.stdout.strip() + ("-dirty" if dirty.stdout.strip() else "")
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def read_run(storage) -> dict | None:
    """The root's run record, None if it has none; RunConfigError if it is damaged."""
    try:
        return read_record(storage, CONFIG_SHAPE)
    except RunRecordError as exc:
        raise RunConfigError(f"{exc}; {REPAIR_HINT}") from None


def _differences(old: dict, new: dict) -> list[str]:
    def shown(k, value):  # the domain entries by their codes
        return [f"{axis} {row['code']}" for axis, rows in (value or {}).items() for row in rows] if k == "catalog" else value

    return [f"{k} {shown(k, old.get(k))!r} -> {shown(k, new.get(k))!r}"
            for k in sorted({*new, *old} if "catalog" in old else new) if old.get(k) != new.get(k)]


def check_rows(storage, config: RunConfig, summaries: dict | None = None) -> None:
    """Frames already in the root must have this run's resolution and seeds
    (run.json can be lost or rewritten; the manifest rows cannot lie).

    Checked from each part's summary (its footer's statistics, or its
    scenario's index): O(parts), no row is decoded. ``summaries``: from
    ``manifests.reader.part_summaries`` if the caller has them already."""
    held = {key: s for key, s in (part_summaries(storage) if summaries is None else summaries).items() if s and s.rows}
    if not held:
        return
    plan = config.plan
    formats = {f for s in held.values() for f in s.rgb}
    if formats - {plan.rgb_format}:
        raise RunConfigError(
            f"{storage.uri} holds {', '.join(sorted(formats))} rgb files, this run asks for {plan.rgb_format}; "
            "frames would not match: use a new --out"
        )
    # a summary holds the (min, max) corners of its rows' sizes: every sensor's, a camera of the rig its own
    asked = set(rig_named(plan.rig).sizes(plan.width, plan.height).values())
    corners = {(min(w for w, _ in asked), min(h for _, h in asked)), (max(w for w, _ in asked), max(h for _, h in asked))}
    sizes = {r for s in held.values() for r in s.resolutions}
    if sizes != corners:
        found, wanted = (", ".join(f"{w}x{h}" for w, h in sorted(them)) for them in (sizes, asked))
        raise RunConfigError(
            f"{storage.uri} holds frames at {found}, this run asks for {wanted}; "
            "frames would not match: use a new --out"
        )
    with using(plan.catalog):
        derived = {key: episode_seed(plan.seed, lookup_scenario(key[0]), key[1], plan.pairing) for key in held}
    for (scenario, episode), summary in sorted(held.items()):
        for seed in summary.seeds:
            if derived[scenario, episode] != seed:
                raise RunConfigError(
                    f"{storage.uri} holds frames made with another run seed than {plan.seed} "
                    f"({scenario} episode {episode}); frames would not match: use a new --out"
                )


def _with_outputs(config: dict) -> dict:
    """A recorded config as today's settings read it: a key a root from before its setting lacks holds
    what it meant then (``pipeline.settings.RECORDED_DEFAULTS``: the six seed outputs, PNG rgb files, one
    frame every 3 s, per-weather episode seeds, the old rules); user weathers recorded with a fog share
    in today's keys (domains.catalog_file.current_layer)."""
    config = {**config, "catalog": current_layer(config["catalog"])} if "catalog" in config else config
    return recorded(config)


def _fresh_record(new: dict, history: list[dict] | None = None, layout: int = NEW_ROOT_LAYOUT,
                  encoder: str | None = None) -> dict:
    """A run record of ``new``; ``encoder``: the root's own (an older root keeps its deflater), else this one's."""
    return {
        "config": new,
        "history": (history or []) + [new],
        "versions": package_versions(),
        "git_revision": git_revision(),
        "encoder": encoder or encoder_identity(new["rgb_format"]),
        LAYOUT_KEY: layout,
    }


def _encoder_held(storage, rgb_format: str) -> str:
    """The encoder for a record written afresh (run.json lost or damaged): with the
    deflater of the PNG files the manifest lists (an ISA-L root keeps ISA-L), else a new root's."""
    for rel in storage.list_files(MANIFEST_DIR + "/", suffix=".parquet")[:8]:
        try:
            table = read_part_file(storage, rel, PART_SCHEMA)
            paths = [(name, p) for name in OUTPUTS for p in table.column(output_columns(name)[0]).to_pylist()[:1]
                     if p is not None and p.endswith(".png")]
            found = deflater_of_files([deflaters_of_png(storage.read_bytes(p), name in PHOTO_OUTPUTS)
                                       for name, p in paths[:3]])  # the rgb file first: it tells zlib-ng's two apart
        except (ManifestError, StorageError, OSError, ValueError):
            continue
        if found is not None:
            return encoder_identity(rgb_format, found)
    return encoder_identity(rgb_format, DEFAULT_DEFLATER)


def _layout_held(storage) -> int:
    """The layout for a record written afresh: that of the frames the manifest
    lists (run.json lost or damaged), else a new root's."""
    return held_layout(storage) or NEW_ROOT_LAYOUT


UNRECORDED_ENCODER = "not recorded (OpenCV's PNG encoder, before encoders were recorded)"


def root_deflater(record: dict | None) -> str:
    """The PNG deflater of a root's frames: the one its run.json names where that is
    installed here (an older root keeps its own), else the default (a new root's)."""
    encoder = (record or {}).get("encoder", "")
    return deflater_named_by(encoder.split("; rgb ", 1)[0]) or DEFAULT_DEFLATER


def for_root(specs, record: dict) -> list:
    """``specs`` as the root of ``record`` renders them: in its layout and with its PNG deflater (an
    older root keeps its own), and in a root of NEW_RULES with each scene's split among the scenes
    of every selection its run.json records (pipeline.planner.scene_places: a scene an earlier run
    asked for keeps its place, so its weathers and longer episodes keep its split)."""
    from dataclasses import replace


    layout, deflater = record_layout(record), root_deflater(record)
    specs = [replace(spec, layout=layout, png_deflater=deflater) for spec in specs]
    if recorded(record["config"])["rules"] < NEW_RULES:
        return specs
    with using(record["config"].get("catalog")):  # the root's domain entries, whoever calls
        places = scene_places([h["domains"] for h in record.get("history", [])] + [record["config"]["domains"]])
        return [replace(spec, split=scene_split(places, lookup_scenario(spec.scenario), spec.episode)) for spec in specs]


def _same_encoder(theirs: str, rgb_format: str) -> bool:
    """True if frames encoded as ``theirs`` can be written here: by the default deflater or the
    root's own older one, with the same JPEG settings."""
    return theirs == encoder_identity(rgb_format, root_deflater({"encoder": theirs}))


def check_encoder(storage, record: dict, rgb_format: str = "png") -> dict:
    """Refuse to add frames encoded otherwise than the root's; records the encoder in an empty root.
    A root written with an older PNG deflater that is still installed keeps it (``root_deflater``)."""
    ours, theirs = encoder_identity(rgb_format), record.get("encoder", UNRECORDED_ENCODER)
    if theirs == ours:
        return record
    if done_episodes(storage):
        if _same_encoder(theirs, rgb_format):
            return record
        raise RunConfigError(
            f"{storage.uri} holds frames written by another encoder ({theirs}; this run writes {ours}); "
            "one root never mixes encoders, since a re-rendered frame would not match its files: "
            "use a new --out, or the encoder that made the root"
        )
    record = {**record, "encoder": ours}
    storage.write_bytes(RUN_FILE, record_bytes(record))
    return read_record(storage, CONFIG_SHAPE)


def changed_entries(old: dict | None, new: dict | None) -> list[str]:
    """The recorded user domain entries (run.json's "catalog") that ``new`` changes or drops,
    as "weather 'FG1'"; appending entries changes none."""
    old, new = old or {}, new or {}
    changed = []
    for axis, rows in old.items():
        now = {row["code"]: row for row in new.get(axis, [])}
        changed += [f"{axis} {row['code']!r}" for row in rows if now.get(row["code"]) != row]
    return changed


def holds_frames(storage) -> bool:
    """Whether the root holds a part or anything beside its own bookkeeping (a scenario
    folder, say): False for a root whose run wrote nothing but its marker and run.json."""
    if storage.list_files(MANIFEST_DIR + "/", suffix=".parquet"):
        return True
    return bool(set(root_entries(storage)) - own_top_names(()))


def _refuse_differences(storage, old: dict, new: dict, extend: bool) -> None:
    """RunConfigError unless a run of ``new`` may add to a root made with ``old``."""
    if old == new:
        return
    if changed := changed_entries(old.get("catalog"), new.get("catalog")):
        raise RunConfigError(
            f"{storage.uri} was made with other parameters for the domain {', '.join(changed)} (run.json "
            "records them); frames would not match: resume without --catalog, with the same entries, or use a new --out"
        )
    diffs = _differences(old, new)
    fixed = [k for k in FRAME_DEFINING if old.get(k) != new.get(k)]
    if fixed and not holds_frames(storage):  # a run that made nothing (killed at once, or refused): say so
        raise RunConfigError(
            f"{storage.uri} holds no frames, but its {RUN_FILE} records a run with another {', '.join(fixed)} "
            f"({'; '.join(diffs)}); run that command, or use a new --out (this one holds nothing to keep)"
        )
    if fixed == ["outputs"]:
        raise RunConfigError(
            f"{storage.uri} holds the outputs {','.join(old['outputs'])}; this run asks for "
            f"{','.join(new['outputs'])}: pass --outputs {','.join(old['outputs'])} to resume it, or use a new --out"
        )
    if fixed:
        raise RunConfigError(
            f"{storage.uri} holds frames made with a different {', '.join(fixed)} ({'; '.join(diffs)}); "
            "frames would not match: use a new --out"
        )
    if not extend:
        raise RunConfigError(
            f"{storage.uri} was produced with another config ({'; '.join(diffs)}); "
            "pass --extend to add to it, or use a new --out"
        )


def check_before_repair(storage, config: RunConfig, extend: bool = False) -> None:
    """Repair's first step, before anything is deleted: a readable run.json
    must describe a run this command may repair (same frame-defining settings,
    and the same config unless ``extend``), and the encoder must be the
    root's. Reads only. A damaged or missing run.json passes: the manifest
    rows are then checked against this command's options instead."""
    try:
        record = read_record(storage, CONFIG_SHAPE)
    except RunRecordError:
        return
    if record is None:
        return
    _refuse_differences(storage, _with_outputs(record["config"]), config.to_dict(), extend)
    theirs = record.get("encoder", UNRECORDED_ENCODER)
    if not _same_encoder(theirs, config.plan.rgb_format) and done_episodes(storage):
        raise RunConfigError(
            f"{storage.uri} holds frames written by another encoder ({theirs}); repair would re-render them "
            "with this one: repair with the encoder that made the root"
        )


def recorded_as_asked(storage, config: RunConfig) -> dict | None:
    """The root's record when its run.json records exactly ``config`` with an encoder this run
    may write: then ``prepare_root`` writes nothing and only checks the rows (``check_rows``),
    which a resume may do beside its first episodes. None otherwise (prepare_root decides)."""
    try:
        record = read_record(storage)
    except RunRecordError:
        return None
    if record is None or _with_outputs(record["config"]) != config.to_dict():
        return None
    theirs, rgb_format = record.get("encoder", UNRECORDED_ENCODER), config.plan.rgb_format
    if theirs != encoder_identity(rgb_format) and not (_same_encoder(theirs, rgb_format) and done_episodes(storage)):
        return None
    return record


def prepare_root(storage, config: RunConfig, extend: bool = False, repair: bool = False,
                 summaries: dict | None = None) -> dict:
    """Record the run in ``run.json``, or check it matches the recorded one.

    The manifest rows are checked too (resolution and seeds). With ``repair``
    a damaged run.json is rewritten from ``config`` when the rows agree.
    Returns the record now in force. Raises RunConfigError on a mismatch.
    ``summaries``: the root's part summaries if the caller has just scanned them.
    """
    new = config.to_dict()
    try:
        record = read_record(storage, CONFIG_SHAPE)
    except RunRecordError as exc:
        if not repair:
            raise RunConfigError(f"{exc}; {REPAIR_HINT}") from None
        if storage.is_local and not os.path.isfile(storage.path(RUN_FILE)):
            raise RunConfigError(f"{exc}; move it away, then run again") from None
        log.warning("rewriting the damaged %s from this run's options", storage.join(RUN_FILE))
        check_rows(storage, config, summaries)
        storage.write_bytes(RUN_FILE, record_bytes(_fresh_record(new, layout=_layout_held(storage),
                                                                 encoder=_encoder_held(storage, new["rgb_format"]))))
        return read_record(storage, CONFIG_SHAPE)
    if record is None:
        check_rows(storage, config, summaries)
        fresh = _fresh_record(new, layout=_layout_held(storage), encoder=_encoder_held(storage, new["rgb_format"]))
        if storage.create_exclusive(RUN_FILE, record_bytes(fresh)):
            return read_record(storage, CONFIG_SHAPE)
        record = read_run(storage)  # another driver was first: compare with its record
        if record is None:
            raise RunConfigError(f"cannot create {storage.join(RUN_FILE)}")
    record = check_encoder(storage, record, config.plan.rgb_format)
    old = _with_outputs(record["config"])
    if old == new:
        check_rows(storage, config, summaries)
        return record
    _refuse_differences(storage, old, new, extend)
    check_rows(storage, config, summaries)
    # a root keeps its layout and its encoder (an ISA-L root stays ISA-L when extended)
    record = _fresh_record(new, record.get("history", [old]), record_layout(record), record.get("encoder"))
    storage.write_bytes(RUN_FILE, record_bytes(record))
    return record


def recorded_config(record: dict) -> RunConfig:
    cfg = _with_outputs(record["config"])
    world = cfg.pop("world", "procedural")
    return RunConfig(plan=PlanConfig(**cfg), world=world)
