"""The IDDA layout, as the published dataset::

    <scenario>/RGB/<frameid>_<scenario>.jpg        the rgb as JPEG, quality 95 (linked from a
                                                   root made with --rgb-format jpg)
    <scenario>/Semantic/<frameid>_<scenario>.png   the semantic_raw image as single-channel class ids
    train.json, val.json, test.json                {scenario: [frame ids]} per split

IDDA's own split files are not documented in the paper; we write one JSON
object per split mapping each exported scenario to its sorted frame ids (every
split file lists every exported scenario, possibly with ``[]``). ``--splits
feddrive`` writes FedDrive's LEAF-style federated splits instead.
"""

from __future__ import annotations

import os
from typing import Callable

from domains.selection import parse_selection
from outputs.encoding import encode_jpeg
from manifests.query import SPLITS
from exports.shared import ExportFrame, Layout, decode, is_jpeg, per_frame, png, write, write_json


def idda_paths(frame: ExportFrame) -> tuple[str, str]:
    """A frame's RGB and Semantic paths in the IDDA layout (the split files list the same)."""
    stem = frame.uid  # <frame_id>_<scenario>, as IDDA names its files
    return f"{frame.scenario}/RGB/{stem}.jpg", f"{frame.scenario}/Semantic/{stem}.png"


def idda_frame(storage, frame: ExportFrame, tmp: str, place) -> dict[str, str]:
    rgb_rel, sem_rel = idda_paths(frame)
    rgb = frame.path("rgb")
    if is_jpeg(rgb):  # already IDDA's format: the file itself, not a second lossy pass
        place(storage, rgb, os.path.join(tmp, rgb_rel))
    else:
        write(os.path.join(tmp, rgb_rel), encode_jpeg(decode(storage, rgb, "rgb"), storage.join(rgb)))
    write(os.path.join(tmp, sem_rel), png(decode(storage, frame.path("semantic_raw"))[..., 0]))
    return {"image": rgb_rel, "semantic": sem_rel}


def idda_dirs(frames: list[ExportFrame]) -> set[str]:
    return {f"{f.scenario}/{sub}" for f in frames for sub in ("RGB", "Semantic")}


def _scenario_split_files(frames: list[ExportFrame], tmp: str, config) -> list[str]:
    """train/val/test.json: {scenario: [frame ids]}, every scenario in every file."""
    scenarios = sorted({f.scenario for f in frames})
    written = []
    for split in SPLITS:
        listing = {s: [] for s in scenarios}
        for f in frames:
            if f.split == split:
                listing[f.scenario].append(f.frame_id)
        written.append(write_json(tmp, f"{split}.json", {s: sorted(ids) for s, ids in listing.items()}))
    return written


# FedDrive's test users (its IDDA settings): frames of the training domains,
# and frames of the held-out domains.
FEDDRIVE_SAME_DOMAIN = "test_user_same_domain"
FEDDRIVE_DIFF_DOMAIN = "test_user_diff_domain"


def _leaf(users: dict[str, list[ExportFrame]]) -> dict:
    """LEAF-style split: users, num_samples, user_data {user: {x: RGB paths, y: Semantic paths}}."""
    names = [u for u, fs in users.items() if fs]
    data = {}
    for user in names:
        ordered = sorted(users[user], key=lambda f: (f.scenario, f.episode, f.frame))
        pairs = [idda_paths(f) for f in ordered]
        data[user] = {"x": [x for x, _ in pairs], "y": [y for _, y in pairs]}
    return {"users": names, "num_samples": [len(data[u]["x"]) for u in names], "user_data": data}


def _feddrive_split_files(frames: list[ExportFrame], tmp: str, config) -> list[str]:
    """FedDrive's federated IDDA splits, one client per training scenario (its
    "heterogeneous" setting): ``feddrive/train/idda_train_clients.json`` holds
    the train frames per scenario; ``feddrive/test/idda_test_clients.json``
    holds ``test_user_same_domain`` (test frames of the training scenarios)
    and, with ``holdout``, ``test_user_diff_domain`` (every frame of the
    held-out scenarios); ``feddrive/val/idda_val_clients.json`` the val
    frames of the training scenarios. Paths are relative to the export root."""
    held = {s.code for s in parse_selection(config.holdout)} if config.holdout else set()
    train: dict[str, list[ExportFrame]] = {}
    val: list[ExportFrame] = []
    same: list[ExportFrame] = []
    diff: list[ExportFrame] = []
    for f in frames:
        if f.scenario in held:
            diff.append(f)
        elif f.split == "train":
            train.setdefault(f.scenario, []).append(f)
        else:
            (val if f.split == "val" else same).append(f)
    return [
        write_json(tmp, "feddrive/train/idda_train_clients.json", _leaf(dict(sorted(train.items())))),
        write_json(tmp, "feddrive/val/idda_val_clients.json", _leaf({FEDDRIVE_SAME_DOMAIN: val})),
        write_json(tmp, "feddrive/test/idda_test_clients.json", _leaf({FEDDRIVE_SAME_DOMAIN: same, FEDDRIVE_DIFF_DOMAIN: diff})),
    ]


SPLIT_FILES: dict[str, Callable] = {
    "scenario": _scenario_split_files,  # train/val/test.json, {scenario: [frame ids]}
    "feddrive": _feddrive_split_files,  # FedDrive's LEAF-style federated splits
}


def split_files(frames: list[ExportFrame], tmp: str, config) -> list[str]:
    return SPLIT_FILES[config.splits](frames, tmp, config)


LAYOUT = Layout(outputs=("rgb", "semantic_raw"), build=per_frame(idda_frame, idda_dirs, split_files))
