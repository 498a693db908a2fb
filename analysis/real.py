"""A real dataset folder in Cityscapes or CamVid layout as one more domain for `idda distances` and `idda shifts`.

The paper's other experiment trains on IDDA and tests on real data. A folder
in Cityscapes' layout takes part in a pair under the name ``real``
(:data:`REAL`)::

    leftImg8bit/<split>/<city>/<name>_leftImg8bit.png     the images (distances, shifts)
    gtFine/<split>/<city>/<name>_gtFine_labelIds.png      Cityscapes label ids (shifts)

A folder in CamVid's layout (``<split>/*.png``, labels in ``<split>annot/``,
:mod:`analysis.camvid`) serves ``idda distances`` as well, its sequences standing
for cities. Its labels hold CamVid's 11 classes, not our 16: it is scored by
``idda shifts --camvid`` (:mod:`analysis.camvid`), not in a shift pair.

Only the chosen splits are read (default ``val``); frames are in (split,
city, name) order. Distances use the images only; shifts also need the
labelIds of every image.

Classes. Cityscapes' 19 evaluated classes map onto our 16 evaluated ones by
the catalog's own table (``domains.catalog.LABELS``: each evaluated class's
``cityscapes_id``, what the Cityscapes export writes), inverted, plus
:data:`OTHER_VEHICLES`: Cityscapes tells truck, bus and train from car, our
``vehicle`` class holds all of them. Every other label id (Cityscapes' ignored
classes, ego vehicle, caravan, trailer) is ignored, as our excluded classes
are. So a Cityscapes export of one of our roots reads back to exactly the
training indices of its frames (the tests check that).

For shifts, the folder's cities stand for episodes: held-out frames are
those of ``val``/``test`` when the chosen splits include ``train`` too (the
oracle then trains on ``train``, Cityscapes' own protocol), else the last
fifth of every city's images (``analysis.shift_table.held_out_mask``).
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from analysis.camvid_layout import camvid_pairs, is_camvid, sequence
from analysis.metrics import IGNORE, TRAIN_INDEX_LUT
from domains.catalog import CLASS_IDS, LABELS

REAL = "real"  # the name a pair uses for the real folder (scenario codes always hold "_")
IMAGES, LABELS_DIR = "leftImg8bit", "gtFine"
IMAGE_SUFFIX, LABEL_SUFFIX = "_leftImg8bit.png", "_gtFine_labelIds.png"
LAYOUT = f"{IMAGES}/<split>/<city>/*{IMAGE_SUFFIX}"
# Cityscapes label ids (cityscapesScripts helpers/labels.py) of its evaluated vehicles other than car.
OTHER_VEHICLES = {27: "truck", 28: "bus", 31: "train"}


def _label_lut() -> np.ndarray:
    lut = np.full(256, IGNORE, dtype=np.uint8)
    for label in LABELS:
        if label.evaluated:
            lut[label.cityscapes_id] = TRAIN_INDEX_LUT[label.id]
    lut[list(OTHER_VEHICLES)] = TRAIN_INDEX_LUT[CLASS_IDS["vehicle"]]
    return lut


# Cityscapes label id -> our training index (analysis.metrics), IGNORE where not scored.
CITYSCAPES_TO_INDEX = _label_lut()


def check_real_pairs(pairs, real: str | None, must_name: bool = True) -> None:
    """ValueError where a pair names ``real`` without a folder, or (``must_name``) a folder is in no pair."""
    named = any(REAL in pair for pair in pairs)
    if named and not real:
        raise ValueError(f"a pair names {REAL!r} but no real folder is given (--real FOLDER)")
    if real and must_name and not named:
        raise ValueError(f"the real folder {real} is in no pair: name it in one, e.g. --pairs T01_CN_A:{REAL}")


@dataclass(frozen=True)
class RealImage:
    split: str
    city: str
    image: str  # path of the leftImg8bit PNG
    label: str  # path of the gtFine labelIds PNG (it may not exist)


@dataclass(frozen=True)
class RealFolder:
    path: str
    splits: tuple[str, ...] = ("val",)

    @property
    def camvid(self) -> bool:
        """Whether the folder is in CamVid's layout rather than Cityscapes'."""
        return not os.path.isdir(os.path.join(self.path, IMAGES)) and is_camvid(self.path)

    def images(self, labels: bool = False) -> list[RealImage]:
        """The chosen splits' images in (split, city, name) order; ValueError saying what is
        missing when the folder is in neither layout (with ``labels``: or lacks labels)."""
        if not self.splits:
            raise ValueError("give at least one split of the real folder")
        if not os.path.isdir(self.path):
            raise ValueError(f"real data folder {self.path} does not exist")
        if self.camvid:
            return [RealImage(split, sequence(image), image, label)
                    for split in self.splits for image, label in camvid_pairs(self.path, split, labels)]
        top = os.path.join(self.path, IMAGES)
        if not os.path.isdir(top):
            raise ValueError(f"{self.path} is not in Cityscapes layout: it has no {IMAGES}/ (expected {LAYOUT})")
        found = sorted(d for d in os.listdir(top) if os.path.isdir(os.path.join(top, d)))
        out = []
        for split in self.splits:
            if split not in found:
                raise ValueError(f"{self.path} has no {IMAGES}/{split}/ (splits there: {', '.join(found) or 'none'})")
            mine = list(self._split(split))
            if not mine:
                raise ValueError(f"{self.path} has no images {IMAGES}/{split}/<city>/*{IMAGE_SUFFIX}")
            out += mine
        if labels:
            _check_labels(self.path, out)
        return out

    def _split(self, split: str):
        base = os.path.join(self.path, IMAGES, split)
        for city in sorted(os.listdir(base)):
            folder = os.path.join(base, city)
            if not os.path.isdir(folder):
                continue
            for name in sorted(n for n in os.listdir(folder) if n.endswith(IMAGE_SUFFIX)):
                stem = name[: -len(IMAGE_SUFFIX)]
                label = os.path.join(self.path, LABELS_DIR, split, city, stem + LABEL_SUFFIX)
                yield RealImage(split, city, os.path.join(folder, name), label)


def _check_labels(path: str, images: list[RealImage]) -> None:
    if not os.path.isdir(os.path.join(path, LABELS_DIR)):
        raise ValueError(f"{path} has no {LABELS_DIR}/: shifts score on "
                         f"{LABELS_DIR}/<split>/<city>/*{LABEL_SUFFIX}")
    missing = [im for im in images if not os.path.isfile(im.label)]
    if missing:
        raise ValueError(f"{path}: {len(missing)} of {len(images)} images have no label ids, "
                         f"e.g. {os.path.relpath(missing[0].label, path)}")


def read_rgb(path: str) -> np.ndarray:
    """An image file as HxWx3 uint8 RGB."""
    from PIL import Image

    with Image.open(path) as image:
        return np.asarray(image.convert("RGB"))


def read_label_ids(path: str) -> np.ndarray:
    """A labelIds PNG as HxW uint8 Cityscapes label ids."""
    from PIL import Image

    with Image.open(path) as image:
        if image.mode not in ("L", "P", "I", "I;16"):
            raise ValueError(f"{path}: label ids must be a one-channel image, got mode {image.mode}")
        ids = np.asarray(image)
    if ids.max(initial=0) > 255 or ids.min(initial=0) < 0:
        raise ValueError(f"{path}: label ids outside 0-255")
    return ids.astype(np.uint8)


def real_features(folder: RealFolder, bank, samples: int, threads: int = 4) -> np.ndarray:
    """Features (analysis.distances.FilterBank) of the first ``samples`` images of the folder."""
    from concurrent.futures import ThreadPoolExecutor

    paths = [im.image for im in folder.images()[:samples]]
    with ThreadPoolExecutor(max_workers=threads) as pool:
        return np.stack(list(pool.map(lambda p: bank(read_rgb(p)), paths)))


def scored_images(folder: RealFolder) -> list[RealImage]:
    """The images and labelIds a shift pair scores on; ValueError for a CamVid folder (11 classes, not our 16)."""
    if folder.camvid:
        raise ValueError(f"{folder.path} is in CamVid layout, whose 11 classes are not our 16: "
                         "measure it with idda shifts --camvid FOLDER, not in a pair")
    return folder.images(labels=True)
