"""The one schema module: plan and manifest layouts, shared by writers,
readers and tests. Column lists derive from the catalog tables."""

from __future__ import annotations

import re

import pyarrow as pa

from domains.catalog import AXES, CODE_CHARS, INSTANCE_LABELS, LABELS, code_axes, scenario_pattern
from domains.conditions import PART_CONDITIONS, VISIBILITY
from outputs.table import CAMERA_OUTPUTS, LIDAR_OUTPUTS

# The root's rules for what its rows and files say (issue 32; docs/layout.md, "Rules of a root"). A new
# root records "rules": 1 in run.json's config; a root made before, without the key, keeps OLD_RULES
# for its life (resume, --extend, --repair and verify read it from run.json):
#   splits: per scene (town, viewpoint, episode: pipeline.planner.scene_places), so every weather of a
#           paired scene has one split; OLD_RULES: per scenario, from its place in the selection
#   flow:   a motion the 16-bit encoding cannot hold is invalid (outputs.encoding.encode_flow);
#           OLD_RULES: clamped to +-512 px and kept valid (outputs.table.OLD_RULE_ENCODERS)
#   fog:    recorded as visibility_m (float64) and blended by shifts in the contrast it leaves
#           (domains.fog); OLD_RULES: fog_density (float32 share per km), blended linearly
OLD_RULES, NEW_RULES = 0, 1
RULES = (OLD_RULES, NEW_RULES)

# ---------------------------------------------------------------- plan ----
PLAN_SCHEMA = pa.schema(
    [
        ("scenario", pa.string()),
        ("town", pa.string()),
        ("weather", pa.string()),
        ("viewpoint", pa.string()),
        ("episode", pa.int32()),
        ("frames", pa.int32()),
        ("seed", pa.int64()),
        ("split", pa.string()),
        ("width", pa.int32()),
        ("height", pa.int32()),
    ]
)
PLAN_CONFIG_KEY = b"idda.plan_config"  # Parquet metadata key holding the config JSON

# ------------------------------------------------------------ manifest ----
# Hive partition keys: directories town=T01/weather=CN/viewpoint=A. They are
# not stored inside the part files; readers get them back from the path.
PARTITION_KEYS = AXES
PARTITION_SCHEMA = pa.schema([(k, pa.string()) for k in PARTITION_KEYS])


def output_columns(output: str) -> tuple[str, str, str]:
    """Manifest columns of one output: relative path, size and checksum."""
    return (f"{output}_path", f"{output}_bytes", f"{output}_sha256")


MATRIX3, MATRIX4 = pa.list_(pa.float64(), 9), pa.list_(pa.float64(), 16)  # row-major 3x3 and 4x4
# (column, type, where frame_row takes it from: the episode spec, the rendered
# frame, or derived from both)
_FRAME_FIELDS = [
    ("frame_id", pa.string(), "derived"),  # <episode:04d>_<frame:03d>; file stem is <frame_id>_<scenario>
    ("uid", pa.string(), "derived"),  # <frame_id>_<scenario>: unique in a root, stable across reruns (frame_uid)
    ("scenario", pa.string(), "spec"),
    ("episode", pa.int32(), "spec"),
    ("frame", pa.int32(), "derived"),  # index within the episode
    ("sim_time_s", pa.float32(), "frame"),  # simulated time of the frame
    ("split", pa.string(), "spec"),
    ("seed", pa.int64(), "spec"),  # the episode's seed
    ("n_vehicles", pa.int16(), "frame"),  # vehicles in the episode's traffic
    ("n_pedestrians", pa.int16(), "frame"),
    ("camera_height_m", pa.float32(), "frame"),
    ("hood_fraction", pa.float32(), "frame"),
    ("ego_speed_mps", pa.float32(), "frame"),
    ("width", pa.int32(), "spec"),
    ("height", pa.int32(), "spec"),
    # Calibration and poses, row-major (outputs.geometry: OpenCV camera axes, world z up, metres), as
    # fixed-size lists: Parquet stores them as the plain lists they were (a part's bytes are the same), and
    # readers given this schema get arrays of known shape. Null in roots written before they existed.
    ("K", MATRIX3, "frame"),  # 3x3 intrinsics in pixels, pixel centres at integers
    ("cam_to_world", MATRIX4, "frame"),  # 4x4
    ("ego_to_world", MATRIX4, "frame"),  # 4x4, the ego's reference point on the road
    ("cam_to_ego", MATRIX4, "frame"),  # 4x4, fixed per viewpoint
    # The weather the frame was rendered under (domains.conditions: units there and in docs/weathers.md).
    # Null in roots written before they existed; fog_density null in roots of rules (visibility_m instead).
    *((c.column, pa.float32(), "condition") for c in PART_CONDITIONS),
]
# Added with rules (manifests.schema.NEW_RULES) after every other column, so no column of older parts moves.
_RULE_FIELDS = [(VISIBILITY.column, pa.float64(), "condition")]
FIELD_SOURCE = {name: source for name, _, source in _FRAME_FIELDS + _RULE_FIELDS}
# An output a run did not ask for has null path, size and checksum.
_OUTPUT_FIELDS = [
    field
    for name in CAMERA_OUTPUTS
    for field in zip(output_columns(name), (pa.string(), pa.int64(), pa.string()))
]
# Added with rigs (domains.rigs) after every other column, and only in the parts of a root whose rig is not the
# default (front): the sensor of the row, then the LiDAR's files. Null in every other part.
RIG_FIELDS = [("sensor", pa.string())] + [
    field
    for name in LIDAR_OUTPUTS
    for field in zip(output_columns(name), (pa.string(), pa.int64(), pa.string()))
]
PIXEL_FIELDS = [(label.column, pa.int64()) for label in LABELS]
OBJECT_FIELDS = [(label.object_column, pa.int32()) for label in INSTANCE_LABELS]  # visible objects per class

# Schema of a part file (one episode); the full manifest adds PARTITION_KEYS.
OLD_PART_SCHEMA = pa.schema([(n, t) for n, t, _ in _FRAME_FIELDS] + _OUTPUT_FIELDS + PIXEL_FIELDS + OBJECT_FIELDS)
RULE_PART_SCHEMA = pa.schema(list(OLD_PART_SCHEMA) + [(n, t) for n, t, _ in _RULE_FIELDS])  # a default-rig part
PART_SCHEMA = pa.schema(list(RULE_PART_SCHEMA) + RIG_FIELDS)  # what readers read; a rig's part
# a part of a root made before rules (manifests.schema.OLD_RULES) has the columns of OLD_PART_SCHEMA only
MANIFEST_SCHEMA = pa.schema(list(PART_SCHEMA) + list(PARTITION_SCHEMA))


def as_plain_lists(table: pa.Table) -> pa.Table:
    """``table`` with its fixed-size lists as the plain lists of files written before they were fixed-size
    (the Arrow schema older indexes and parts store), so verify can re-encode such a file as it was."""
    schema = pa.schema([pa.field(f.name, pa.list_(f.type.value_type)) if pa.types.is_fixed_size_list(f.type) else f
                        for f in table.schema], metadata=table.schema.metadata)
    return table.cast(schema)


MANIFEST_DIR = "manifest"  # <root>/manifest/town=../weather=../viewpoint=../<scenario>_eNNNN_n<rows>.parquet
RUN_FILE = "run.json"  # <root>/run.json: config, versions, git revision
STATS_DIR = "_stats"  # <root>/_stats/<scenario>_eNNNN.json: worker timings (not part of the data)


def frame_id(episode: int, frame: int) -> str:
    return f"{episode:04d}_{frame:03d}"


def frame_stem(fid: str, scenario: str, sensor: str = "") -> str:
    """The stem of a frame's files, ``<frame_id>_<scenario>`` (a rig's sensor: ``..._<sensor>``): its uid too."""
    return f"{fid}_{scenario}_{sensor}" if sensor else f"{fid}_{scenario}"


def frame_uid(scenario: str, episode: int, frame: int, sensor: str = "") -> str:
    """A frame's id, unique in its root and the same in every rerun: ``<episode:04d>_<frame:03d>_<scenario>``,
    the stem of its files."""
    return frame_stem(frame_id(episode, frame), scenario, sensor)


def with_uids(table: pa.Table) -> pa.Table:
    """``table`` (manifest rows) with its ``uid`` column filled where it is null (roots written before it existed)."""
    import pyarrow.compute as pc

    derived = pc.binary_join_element_wise(table.column("frame_id"), table.column("scenario"), "_")
    if "uid" not in table.column_names:
        return table.append_column("uid", derived)
    if table.column("uid").null_count == 0:
        return table
    return table.set_column(table.column_names.index("uid"), "uid", pc.coalesce(table.column("uid"), derived))


# Per-scenario compaction of its parts (see manifests.reader.compact). Indexes
# live OUTSIDE manifest/, so a reader that globs manifest/**/*.parquet (DuckDB,
# Polars, HF datasets) sees exactly one row per frame. An index holds the full
# MANIFEST_SCHEMA, partition columns included.
INDEX_DIR = "_index"  # <root>/_index/<scenario>.parquet
INDEX_EPISODES_KEY = b"idda.index_episodes"  # footer metadata: episodes the index covers
# footer metadata: what the index was built from, one JSON item per part:
# [episode, part bytes, rows, seeds, resolutions, rgb formats] (manifests.reader.PartSummary)
INDEX_PARTS_KEY = b"idda.index_parts"
LEGACY_INDEX_NAME = "_index.parquet"  # where older versions put indexes (inside manifest/); compaction removes them


def index_path(scenario: str) -> str:
    return f"{INDEX_DIR}/{scenario}.parquet"


def part_stem(scenario: str, episode: int) -> str:
    """What every name of an episode's part starts with: ``<scenario>_e<episode:04d>``."""
    return f"{scenario}_e{episode:04d}"


def stats_path(scenario: str, episode: int) -> str:
    """Where a worker writes an episode's timings: ``_stats/<scenario>_e<episode:04d>.json``."""
    return f"{STATS_DIR}/{part_stem(scenario, episode)}.json"


# An episode's stats file (stats_path): groups scenario and episode; any code the catalog allows.
STATS_RE = re.compile("^" + STATS_DIR + "/" + scenario_pattern(axes=False) + r"_e(?P<episode>\d{4})\.json$")


def part_path(scenario: str, episode: int, rows: int | None = None) -> str:
    """Relative path of an episode's manifest part (its "done" marker).

    ``rows``: the part's row count, which its name carries (``..._e0003_n72.parquet``)
    so that a listing alone says how many frames each part holds (``idda status``
    reads no part). Every part is written so; None gives the name parts had
    before (``..._e0003.parquet``), which old roots keep and readers still read
    (``PART_RE``)."""
    hive = "/".join(f"{axis}={value}" for axis, value in code_axes(scenario).items())
    counted = "" if rows is None else f"_n{int(rows)}"
    return f"{MANIFEST_DIR}/{hive}/{part_stem(scenario, episode)}{counted}.parquet"


# A part's path, old names and counted ones: groups town, weather, viewpoint,
# scenario, episode and rows (None in an old name). Any code the catalog allows
# (domains.catalog: CODE_CHARS, scenario_pattern).
PART_RE = re.compile(
    "^" + MANIFEST_DIR + "/" + "/".join(f"{axis}=(?P<{axis}>{CODE_CHARS})" for axis in AXES) + "/"
    + scenario_pattern(axes=False) + r"_e(?P<episode>\d{4})(?:_n(?P<rows>[1-9]\d*))?\.parquet$"
)


def named_rows(rel: str) -> int | None:
    """The row count a part's name carries; None for an old name (or not a part)."""
    match = PART_RE.match(rel)
    return None if match is None or match.group("rows") is None else int(match.group("rows"))


def newer_part(rel: str, other: str) -> bool:
    """Whether ``rel`` is the part to read where ``other`` names the same episode
    too (a writer killed between writing a part and removing its old name): a
    counted name over an old one, then the one with more rows (an episode is
    rendered again only when its part held fewer frames than the plan asks)."""
    rank = [-1 if n is None else n for n in (named_rows(rel), named_rows(other))]
    return rank[0] > rank[1]
