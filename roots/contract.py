"""The output root's contract: what marks a directory as ours, and what may be
written into, replaced in or deleted from it.

* A root is ours if it carries ``idda-root.json`` (written before any frame),
  or, for roots made before the marker existed, both ``run.json`` and a
  ``manifest/`` folder. ``idda produce`` refuses any other non-empty
  directory (or S3 prefix) as ``--out``.
* Inside a root, repair deletes only files whose paths follow the root's own
  file layout (``manifests.layout.match_frame_file``: the flat layout of an
  old root, or a new root's episode folders); anything else is left alone.
* An export target may never be inside a root or hold one, at any depth; a
  non-empty target is replaced (``--force``) only when it is a finished export
  of ours that holds exactly what that export wrote: ``EXPORT.json`` lists the
  tree it wrote (:func:`export_tree`), and one file or folder more or less
  means the target is refused. Symlinks are never followed, when checking or
  when deleting.
"""

from __future__ import annotations

import hashlib
import json
import os

from roots.lease import LEASE_DIR
from manifests.schema import INDEX_DIR, MANIFEST_DIR, RUN_FILE, STATS_DIR

ROOT_MARKER = "idda-root.json"  # <root>/idda-root.json: "this directory is an idda output root"
CARD_FILE = "README.md"  # <root>/README.md: the dataset card (`idda card`)
CHART_FILE = "class_shares.png"  # <root>/class_shares.png: the card's class-share chart
PREVIEW_DIR = "preview"  # <root>/preview/: the card's contact sheet
ROOT_MARKER_BODY = (json.dumps({"idda_output_root": 1, "contract": "see docs/contract.md of idda-pipeline"}) + "\n").encode()
EXPORT_MARKER = "EXPORT.json"  # written last into an export: a finished export of ours


class RootError(ValueError):
    """A directory is used against the root's contract (not ours, or inside one of ours)."""


def _is_hidden_temp(name: str) -> bool:
    return name.startswith(".")  # temp files, write probes, OS litter (.DS_Store)


def root_entries(storage) -> list[str]:
    """Top-level names under the root (hidden names left out); [] if it does not exist.

    Names only, no stat: another driver creating the same root at this moment
    writes and deletes a probe file there, and a listing that stats each entry
    failed on the vanished probe."""
    return [name for name in storage.entries() if not _is_hidden_temp(name)]


def own_top_names(scenarios) -> frozenset[str]:
    """The top-level names a root's own files and folders have: its marker, run.json,
    the manifest, indexes, stats and leases, the card's files, and a folder per
    scenario of ``scenarios`` (codes; the root's catalog). Any other name is foreign:
    verify lists it, nothing deletes it."""
    return frozenset({ROOT_MARKER, RUN_FILE, MANIFEST_DIR, INDEX_DIR, STATS_DIR, LEASE_DIR,
                      CARD_FILE, CHART_FILE, PREVIEW_DIR, *scenarios})


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
    if storage.is_local:
        outer = enclosing_root(storage.path())
        if outer is not None:
            raise RootError(f"{storage.uri} is inside the output root {outer}; use a directory outside any output root as --out")
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
    # A new root is marked; one made before the marker existed stays as it is,
    # so a command that then refuses (a repair) leaves it byte for byte.
    if not entries:
        storage.create_exclusive(ROOT_MARKER, ROOT_MARKER_BODY)


def _is_root_dir(path: str) -> bool:
    """A local directory that is an output root (marker, or run.json with a manifest/)."""
    return os.path.isfile(os.path.join(path, ROOT_MARKER)) or (
        os.path.isfile(os.path.join(path, RUN_FILE)) and os.path.isdir(os.path.join(path, MANIFEST_DIR))
    )


def enclosing_root(path: str) -> str | None:
    """The nearest output root that holds the local ``path`` (its real path) below it, or None."""
    ancestor = os.path.realpath(path)
    while os.path.dirname(ancestor) != ancestor:
        ancestor = os.path.dirname(ancestor)
        if _is_root_dir(ancestor):
            return ancestor
    return None


def export_tree(path: str) -> dict:
    """What a local export directory holds, as ``EXPORT.json`` records it.

    Every entry below ``path`` (files, folders with a trailing ``/``,
    symlinks as entries: never followed), except the top-level
    ``EXPORT.json`` itself: ``{"entries": count, "sha256": digest of the
    sorted relative paths, "top": sorted top-level names}``.
    """
    paths = []
    for folder, dirs, files in os.walk(path, followlinks=False):
        rel = os.path.relpath(folder, path)
        prefix = "" if rel == "." else rel.replace(os.sep, "/") + "/"
        for name in dirs:  # symlinks to folders are listed here too, and not entered
            link = os.path.islink(os.path.join(folder, name))
            paths.append(prefix + name + ("" if link else "/"))
        paths.extend(prefix + name for name in files)
    paths = sorted(p for p in paths if p != EXPORT_MARKER)
    digest = hashlib.sha256("\n".join(paths).encode()).hexdigest()
    top = sorted({p.split("/", 1)[0] for p in paths})
    return {"entries": len(paths), "sha256": digest, "top": top}


def _held_root(real: str) -> str | None:
    """The first output root at any depth below ``real`` (symlinks not followed), or None."""
    for folder, dirs, _ in os.walk(real, followlinks=False):
        dirs.sort()
        for name in dirs:
            path = os.path.join(folder, name)
            if not os.path.islink(path) and _is_root_dir(path):
                return path
    return None


def _export_mismatch(real: str, recorded) -> str | None:
    """Why the export directory ``real`` is not exactly what its EXPORT.json says it wrote (None: it is)."""
    if not isinstance(recorded, dict) or not {"entries", "sha256", "top"} <= set(recorded):
        return f"its {EXPORT_MARKER} does not list what it wrote (an export by an older idda)"
    found = export_tree(real)
    if found["sha256"] == recorded["sha256"]:
        return None
    foreign = sorted(set(found["top"]) - set(recorded["top"]))
    if foreign:
        return f"it holds {foreign[0]!r}, which the export did not write"
    return f"its content changed since the export ({found['entries']} entries, the export wrote {recorded['entries']})"


def check_export_target(target: str, force: bool) -> None:
    """Refuse an export target that could destroy data.

    A target that is a symlink, is inside an output root, or is or holds one
    at any depth is always refused. A non-empty target is replaced only with
    ``force`` and only if it is a finished export of ours holding exactly the
    tree its EXPORT.json records (:func:`export_tree`).
    """
    if os.path.islink(target):
        raise RootError(f"export target {target} is a symlink; give a real directory (symlinks are never followed)")
    real = os.path.realpath(target)
    if os.path.lexists(target) and not os.path.isdir(target):
        raise ValueError(f"export target {target} exists and is not a directory")
    if _is_root_dir(real):
        raise RootError(f"export target {target} is an output root; export outside any output root")
    outer = enclosing_root(real)
    if outer is not None:
        raise RootError(f"export target {target} is inside the output root {outer}; export outside any output root")
    if not os.path.isdir(real) or not os.listdir(real):
        return
    held = _held_root(real)
    if held is not None:
        raise RootError(
            f"export target {target} holds the output root {os.path.join(target, os.path.relpath(held, real))}; "
            "export elsewhere"
        )
    if not force:
        raise ValueError(f"export target {target} is not empty; pass --force to replace it")
    marker = os.path.join(real, EXPORT_MARKER)
    if not os.path.isfile(marker) or os.path.islink(marker):
        raise RootError(
            f"export target {target} is not empty and is not an earlier export (no {EXPORT_MARKER}); "
            "--force replaces only an export; choose an empty or new directory"
        )
    try:
        with open(marker, "rb") as f:
            recorded = json.loads(f.read()).get("tree")
    except (OSError, ValueError, AttributeError):
        recorded = None
    why = _export_mismatch(real, recorded)
    if why is not None:
        raise RootError(
            f"export target {target} is not only what an earlier export wrote: {why}; "
            "--force deletes only an export's own files; choose an empty or new directory"
        )
