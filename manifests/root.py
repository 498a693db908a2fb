"""The output root's contract: what marks a directory as ours, and what may be
written into, replaced in or deleted from it.

* A root is ours if it carries ``idda-root.json`` (written before any frame),
  or, for roots made before the marker existed, both ``run.json`` and a
  ``manifest/`` folder. ``idda produce`` refuses any other non-empty
  directory (or S3 prefix) as ``--out``.
* Inside a root, repair deletes only files whose names match our layout
  (``FRAME_FILE_RE``); anything else is left alone.
* An export target may never be inside a root or hold one; a non-empty target
  is replaced (``--force``) only when it is a finished export of ours, which
  carries ``EXPORT.json``.
"""

from __future__ import annotations

import json
import os
import re

import pyarrow.fs as pafs

from manifests.outputs import FORMATS, OUTPUT_TABLE, OUTPUTS
from manifests.schema import MANIFEST_DIR, RUN_FILE

ROOT_MARKER = "idda-root.json"  # <root>/idda-root.json: "this directory is an idda output root"
ROOT_MARKER_BODY = (json.dumps({"idda_output_root": 1, "contract": "see docs/contract.md of idda-pipeline"}) + "\n").encode()
EXPORT_MARKER = "EXPORT.json"  # written last into an export: a finished export of ours

# <scenario>/<output>/<episode:04d>_<frame:03d>_<scenario>.<its extension>, the
# only files repair may delete from a scenario folder.
_BY_EXTENSION: dict[str, list[str]] = {}
for _o in OUTPUT_TABLE:
    for _file in _o.files:  # the rgb output's PNG or JPEG
        _BY_EXTENSION.setdefault(FORMATS[_file].extension, []).append(_o.name)
FRAME_FILE_RE = re.compile(
    r"^(?P<scenario>T\d\d_[A-Z]+_[A-Z])/"
    + "(?=" + "|".join(f"(?:{'|'.join(names)})/[^/]*\\.{ext}$" for ext, names in _BY_EXTENSION.items()) + ")"
    + r"(?P<output>" + "|".join(OUTPUTS) + r")/"
    r"(?P<episode>\d{4})_(?P<frame>\d{3})_(?P=scenario)\.[a-z0-9]+$"
)
del _o, _file


class RootError(ValueError):
    """A directory is used against the root's contract (not ours, or inside one of ours)."""


def _is_hidden_temp(name: str) -> bool:
    return name.startswith(".")  # temp files, write probes, OS litter (.DS_Store)


def root_entries(storage) -> list[str]:
    """Top-level names under the root (hidden names left out); [] if it does not exist."""
    selector = pafs.FileSelector(storage.path(), recursive=False, allow_not_found=True)
    try:
        infos = storage.filesystem.get_file_info(selector)
    except (OSError, ValueError) as exc:
        from storage.errors import storage_error

        raise storage_error("list", storage.uri, exc) from exc
    return sorted(i.base_name for i in infos if not _is_hidden_temp(i.base_name))


def is_our_root(storage) -> bool:
    """True if ``storage`` carries our marker, or is a root made before the marker."""
    if storage.exists(ROOT_MARKER):
        return True
    return storage.exists(RUN_FILE) and bool(storage.list_files(MANIFEST_DIR + "/", suffix=".parquet"))


def require_root(storage) -> None:
    """RootError, in the one sentence every command gives, unless ``storage``
    looks like an output root: our marker, a ``run.json`` or a manifest part
    (a root a crash left before its first part still has the first two)."""
    if storage.exists(ROOT_MARKER) or storage.exists(RUN_FILE):
        return
    if storage.list_files(MANIFEST_DIR + "/", suffix=".parquet"):
        return
    raise RootError(
        f"{storage.uri} is not an output root (no {ROOT_MARKER}, {RUN_FILE} or {MANIFEST_DIR}/ there); "
        f"`idda produce --out {storage.uri}` makes one"
    )


def claim_root(storage) -> None:
    """Mark ``storage`` as ours before anything is written into it (creating it).

    An empty (or absent) root, or one of ours, is fine; anything else raises
    RootError and nothing is written. StorageError if it is not writable.
    """
    if storage.exists(ROOT_MARKER):
        storage.ensure_writable()
        return
    entries = root_entries(storage)
    if entries and not is_our_root(storage):
        shown = ", ".join(entries[:5]) + (" ..." if len(entries) > 5 else "")
        raise RootError(
            f"{storage.uri} is not empty ({shown}) and is not an idda output root (no {ROOT_MARKER}); "
            "use a new or empty directory as --out"
        )
    storage.ensure_writable()
    storage.create_exclusive(ROOT_MARKER, ROOT_MARKER_BODY)


def _is_root_dir(path: str) -> bool:
    """A local directory that is an output root (marker, or run.json with a manifest/)."""
    return os.path.isfile(os.path.join(path, ROOT_MARKER)) or (
        os.path.isfile(os.path.join(path, RUN_FILE)) and os.path.isdir(os.path.join(path, MANIFEST_DIR))
    )


def check_export_target(target: str, force: bool) -> None:
    """Refuse an export target that could destroy data.

    A target inside an output root, or that is or holds one, is always refused.
    A non-empty target is replaced only with ``force`` and only if it is a
    finished export of ours (it carries EXPORT.json).
    """
    real = os.path.realpath(target)
    if os.path.lexists(target) and not os.path.isdir(target):
        raise ValueError(f"export target {target} exists and is not a directory")
    if _is_root_dir(real):
        raise RootError(f"export target {target} is an output root; export outside any output root")
    ancestor = real
    while os.path.dirname(ancestor) != ancestor:
        ancestor = os.path.dirname(ancestor)
        if _is_root_dir(ancestor):
            raise RootError(f"export target {target} is inside the output root {ancestor}; export outside any output root")
    if not os.path.isdir(real) or not os.listdir(real):
        return
    held = [name for name in sorted(os.listdir(real)) if os.path.isdir(os.path.join(real, name)) and _is_root_dir(os.path.join(real, name))]
    if held:
        raise RootError(f"export target {target} holds the output root {os.path.join(target, held[0])}; export elsewhere")
    if not force:
        raise ValueError(f"export target {target} is not empty; pass --force to replace it")
    if not os.path.isfile(os.path.join(real, EXPORT_MARKER)):
        raise RootError(
            f"export target {target} is not empty and is not an earlier export (no {EXPORT_MARKER}); "
            "--force replaces only an export; choose an empty or new directory"
        )
