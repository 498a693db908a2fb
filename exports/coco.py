"""The COCO layout (``idda export --format coco``): instances as RLE masks and boxes.

::

    images/<split>/<frameid>_<scenario>.png     the rgb (linked; .jpg from a root made with --rgb-format jpg)
    annotations/instances_<split>.json          COCO instances, one file per split

Categories are the instance classes (``Label.instances``) with their IDDA
class ids. One annotation per visible object of the frame's ``objects``
sidecar: ``segmentation`` is its visible mask from the ``instance`` PNG as a
compressed RLE (pycocotools), ``bbox`` the sidecar's tight box ``[x, y, w,
h]``, ``area`` its visible pixel count, ``iscrowd`` 0; the IDDA extras
``instance_id``, ``occlusion``, ``truncation`` and ``box3d`` (centre, size,
yaw in the OpenCV camera frame) ride along. The ego hood is not an object.
Each ``images`` entry also carries ``idda_uid`` (unique in the root), ``K``
(row-major 3x3) and ``cam_to_world`` (row-major 4x4), as docs/conventions.md
states them (null for roots written before they existed).
pycocotools' ``COCO(annotation_file)`` reads the files as they are.
"""

from __future__ import annotations

import json
import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from domains.catalog import INSTANCE_LABELS
from exports.shared import FILE_MODES, Layout, decode

ANNOTATIONS = "annotations/instances_{split}.json"


def _mask_api():
    try:
        from pycocotools import mask
    except ImportError as exc:
        raise ImportError("the coco export needs pycocotools: pip install 'idda-pipeline[coco]'") from exc
    return mask


def categories() -> list[dict]:
    return [{"id": label.id, "name": label.name, "supercategory": "object"} for label in INSTANCE_LABELS]


def frame_annotations(instance: np.ndarray, objects) -> list[dict]:
    """COCO annotations (without image and annotation ids) of one frame."""
    mask_api = _mask_api()
    out = []
    for row in objects.to_pylist():
        mask = np.asfortranarray((instance == row["instance_id"]).astype(np.uint8))
        rle = mask_api.encode(mask)
        rle["counts"] = rle["counts"].decode("ascii")
        out.append({
            "category_id": row["class_id"],
            "segmentation": rle,
            "area": row["pixels"],
            "bbox": [row["x0"], row["y0"], row["x1"] - row["x0"], row["y1"] - row["y0"]],
            "iscrowd": 0,
            "instance_id": row["instance_id"],
            "occlusion": round(row["occlusion"], 4),
            "truncation": round(row["truncation"], 4),
            "box3d": {"centre": [row["cx"], row["cy"], row["cz"]],
                      "size": [row["length"], row["width"], row["height"]], "yaw": row["yaw"]},
        })
    return out


def write_coco(storage, frames: list, tmp: str, place, threads: int = 8) -> tuple[list[dict], list[str]]:
    """Images and per-split annotation files into ``tmp``; returns each frame's files and the extra files."""
    _mask_api()

    def one(frame) -> tuple[str, list[dict]]:
        rel = f"images/{frame.split}/{frame.uid}{os.path.splitext(frame.path('rgb'))[1]}"
        place(storage, frame.path("rgb"), os.path.join(tmp, rel))
        anns = frame_annotations(decode(storage, frame.path("instance"), "instance"),
                                 decode(storage, frame.path("objects"), "objects"))
        return rel, anns

    for split in sorted({f.split for f in frames}):
        os.makedirs(os.path.join(tmp, "images", split), exist_ok=True)
    with ThreadPoolExecutor(max_workers=threads) as pool:
        done = list(pool.map(one, frames))
    per_split: dict[str, dict] = {}
    exported = []
    for frame, (rel, anns) in zip(frames, done):
        coco = per_split.setdefault(frame.split, {"images": [], "annotations": [], "categories": categories()})
        image_id = len(coco["images"]) + 1
        height, width = frame.height, frame.width
        coco["images"].append({"id": image_id, "file_name": os.path.relpath(rel, "images"), "width": width,
                               "height": height, "idda_frame_id": frame.frame_id, "idda_uid": frame.uid,
                               "scenario": frame.scenario, "K": frame.K, "cam_to_world": frame.cam_to_world})
        for ann in anns:
            coco["annotations"].append({"id": len(coco["annotations"]) + 1, "image_id": image_id, **ann})
        exported.append({"image": rel, "annotations": ANNOTATIONS.format(split=frame.split)})
    extras = []
    for split, coco in sorted(per_split.items()):
        rel = ANNOTATIONS.format(split=split)
        os.makedirs(os.path.dirname(os.path.join(tmp, rel)), exist_ok=True)
        with open(os.path.join(tmp, rel), "w") as f:
            json.dump({"info": {"description": "IDDA re-creation, instances"}, **coco}, f)
        extras.append(rel)
    return exported, extras


def _build(storage, frames: list, tmp: str, config) -> tuple[list[dict], list[str]]:
    return write_coco(storage, frames, tmp, FILE_MODES[config.files], threads=config.threads)


LAYOUT = Layout(outputs=("rgb", "instance", "objects"), build=_build)
