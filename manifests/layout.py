"""Where a root keeps its frame files: the one place that builds or parses a
frame file's path (docs/layout.md).

Two layouts, recorded as ``run.json``'s ``"layout"``:

* ``EPISODE_DIRS`` (2, every new root): ``<scenario>/e<episode>/<output>/<frame_id>_<scenario>.<ext>``,
  so a folder holds at most one episode's frames of one output (60-80 at full
  scale) and a scenario folder one sub-folder per episode.
* ``FLAT`` (1, roots whose run.json has no ``"layout"``: made before layouts
  were recorded): ``<scenario>/<output>/<frame_id>_<scenario>.<ext>``, up to
  21,400 files in one folder at full scale.

A root is in one layout only: resuming, extending, verifying and repairing an
old root keeps it flat. The manifest rows store each file's path, so readers
that go through the ``<output>_path`` columns never need to know the layout.
"""

from __future__ import annotations

import re

from domains.catalog import scenario_pattern
from manifests.part_file import ManifestError, read_part_file
from outputs.table import FORMATS, OUTPUT_TABLE, OUTPUTS, extension
from manifests.schema import MANIFEST_DIR, PART_SCHEMA, frame_stem, output_columns
from storage import StorageError

FLAT = 1
EPISODE_DIRS = 2
LAYOUTS = (FLAT, EPISODE_DIRS)
NEW_ROOT_LAYOUT = EPISODE_DIRS
LAYOUT_KEY = "layout"  # run.json's top-level key; absent: FLAT

PATTERNS = {  # a frame file's path in each layout, as the docs and the dataset card write it
    FLAT: "<scenario>/<output>/<episode>_<frame>_<scenario>",
    EPISODE_DIRS: "<scenario>/e<episode>/<output>/<episode>_<frame>_<scenario>",
}


def check_layout(layout) -> int:
    """``layout`` if it is a known layout; ValueError otherwise."""
    if isinstance(layout, bool) or layout not in LAYOUTS:
        raise ValueError(f"unknown file layout {layout!r} (known: {', '.join(map(str, LAYOUTS))})")
    return layout


def output_dir(scenario: str, name: str, episode: int, layout: int, sensor: str = "") -> str:
    """The folder holding episode ``episode``'s files of output ``name`` (of a rig's ``sensor``:
    ``<scenario>/e<episode>/<sensor>/<output>``, in the episode-folder layout only)."""
    if check_layout(layout) == FLAT:
        if sensor:
            raise ValueError("a rig's sensors need the episode-folder layout")
        return f"{scenario}/{name}"
    return f"{scenario}/e{episode:04d}/{sensor}/{name}" if sensor else f"{scenario}/e{episode:04d}/{name}"


def frame_path(scenario: str, name: str, fid: str, rgb_format: str, layout: int, sensor: str = "") -> str:
    """Relative path of one output file of frame ``fid`` (``<episode:04d>_<frame:03d>``);
    the rgb output's extension is the root's rgb format. A rig's ``sensor`` has its own folder and
    its name at the end of the stem."""
    episode = int(fid.partition("_")[0])
    return (f"{output_dir(scenario, name, episode, layout, sensor)}/{frame_stem(fid, scenario, sensor)}."
            f"{extension(name, rgb_format)}")


# The names of frame files, the only files repair may delete from a scenario
# folder: an output's folder, a frame id whose episode is the folder's, and
# that output's extension (the rgb output's PNG or JPEG).
_BY_EXTENSION: dict[str, list[str]] = {}
for _o in OUTPUT_TABLE:
    for _file in _o.files:
        _BY_EXTENSION.setdefault(FORMATS[_file].extension, []).append(_o.name)
del _o, _file
_SCENARIO = "^" + scenario_pattern(axes=False) + "/"  # any code the catalog allows
_OUTPUT = (
    "(?=" + "|".join(f"(?:{'|'.join(names)})/[^/]*\\.{ext}$" for ext, names in _BY_EXTENSION.items()) + ")"
    + r"(?P<output>" + "|".join(OUTPUTS) + r")/"
)
_NAME = r"(?P<frame>\d{3})_(?P=scenario)\.[a-z0-9]+$"
_SENSOR_NAME = r"(?P<frame>\d{3})_(?P=scenario)(?(sensor)_(?P=sensor))\.[a-z0-9]+$"
_SENSOR = r"(?:(?P<sensor>(?!(?:" + "|".join(OUTPUTS) + r")/)[a-z][a-z0-9]*)/)?"  # domains.rigs.NAME_RE
FRAME_FILE_RES = {
    FLAT: re.compile(_SCENARIO + _OUTPUT + r"(?P<episode>\d{4})_" + _NAME),
    EPISODE_DIRS: re.compile(_SCENARIO + r"e(?P<episode>\d{4})/" + _SENSOR + _OUTPUT + r"(?P=episode)_" + _SENSOR_NAME),
}


def match_frame_file(rel: str, layouts: tuple[int, ...] = LAYOUTS) -> re.Match | None:
    """The match of ``rel`` against the frame file names of ``layouts`` (groups
    scenario, output, episode, frame), or None: not a frame file of theirs."""
    for layout in layouts:
        match = FRAME_FILE_RES[layout].match(rel)
        if match:
            return match
    return None


def layout_of_path(rel: str) -> int | None:
    """The layout a frame file's path follows, or None."""
    return next((layout for layout in LAYOUTS if FRAME_FILE_RES[layout].match(rel)), None)


def record_layout(record: dict) -> int:
    """The layout of a root whose run.json holds ``record`` (no key: FLAT, an old root)."""
    return check_layout(record.get(LAYOUT_KEY, FLAT))


def held_layout(storage, parts: int = 8) -> int | None:
    """The layout of the frames a root's manifest lists, from the first readable
    of its first ``parts`` parts; None if it has none (for a root whose run.json
    is lost or damaged)."""
    for rel in storage.list_files(MANIFEST_DIR + "/", suffix=".parquet")[:parts]:
        try:
            table = read_part_file(storage, rel, PART_SCHEMA)
        except (ManifestError, StorageError, OSError):
            continue
        for name in OUTPUTS:
            paths = [p for p in table.column(output_columns(name)[0]).to_pylist()[:1] if p is not None]
            if paths and layout_of_path(paths[0]) is not None:
                return layout_of_path(paths[0])
    return None
