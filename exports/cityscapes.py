"""The Cityscapes layout: what cityscapesScripts and Cityscapes data loaders expect::

    leftImg8bit/<split>/<city>/<name>_leftImg8bit.png       the rgb (linked; from a root made with
                                                            --rgb-format jpg: the JPEG's pixels as a PNG)
    gtFine/<split>/<city>/<name>_gtFine_labelIds.png        Cityscapes label ids
    gtFine/<split>/<city>/<name>_gtFine_labelTrainIds.png   trainIds, 255 = ignore
    gtFine/<split>/<city>/<name>_gtFine_color.png           Cityscapes colours (RGBA)
    gtFine/<split>/<city>/<name>_gtFine_instanceIds.png     instances (16 bit)
    camera/<split>/<city>/<name>_camera.json                 calibration, Cityscapes' camera format

``<name>`` is ``<city>_<episode:06d>_<frame:06d>`` with ``<city>`` the scenario
code with ``-`` for ``_`` (``T01-CS-A``): cityscapesScripts splits file names at
``_`` into city, sequence and frame, and finds a prediction for a ground-truth
file by the pattern ``<city>_<seq>_<frame>*.png``. The instance image holds, as
Cityscapes does, ``label id * 1000 + index`` on the objects of Cityscapes'
instance classes (person, rider, car, motorcycle, bicycle; index counts the
frame's objects of that class from 0, in instance id order) and the label id
elsewhere (the hood too). A root produced without the ``instance`` output gets
label ids only. Excluded IDDA classes map to Cityscapes ids that the
evaluation ignores.

The camera file is Cityscapes' (cityscapesScripts docs/csCalibration.pdf):
``intrinsic`` {fx, fy, u0, v0} in pixels from the row's ``K``; ``extrinsic``
{x, y, z} the camera's position in the vehicle frame (ISO 8855: x forward,
y left, z up; metres) and {yaw, pitch, roll} in radians, the rotation
``Rz(yaw) @ Ry(pitch) @ Rx(roll)`` (the pdf's eq. 3) from a camera frame
with the vehicle's axes to the vehicle frame, from the row's ``cam_to_ego``
(its eq. 6 turns those axes into OpenCV's: ``CV_FROM_VEHICLE_AXES``). ``baseline`` is 0:
the ego camera is mono, there is no right image. Our ego frame has the
vehicle's axes but its origin on the road under the ego's centre, where
Cityscapes' is under the rear axle (docs/conventions.md).
"""

from __future__ import annotations

import math
import os

import numpy as np

from domains.catalog import CITYSCAPES_ID_LUT, LABELS, TRAIN_ID_LUT
from outputs.encoding import decode_png16
from outputs.geometry import as_matrix
from outputs.objects import HOOD_ID
from exports.shared import ExportFrame, Layout, decode, is_jpeg, per_frame, png, write, write_json

# Cityscapes label ids and colours (cityscapesScripts helpers/labels.py) for
# the ids the catalog maps to; the gtFine colour image derives from this.
CITYSCAPES_COLORS: dict[int, tuple[int, int, int]] = {
    0: (0, 0, 0),  # unlabeled
    4: (0, 0, 0),  # static
    5: (111, 74, 0),  # dynamic
    6: (81, 0, 81),  # ground
    7: (128, 64, 128),  # road
    8: (244, 35, 232),  # sidewalk
    10: (230, 150, 140),  # rail track
    11: (70, 70, 70),  # building
    12: (102, 102, 156),  # wall
    13: (190, 153, 153),  # fence
    14: (180, 165, 180),  # guard rail
    17: (153, 153, 153),  # pole
    19: (250, 170, 30),  # traffic light
    20: (220, 220, 0),  # traffic sign
    21: (107, 142, 35),  # vegetation
    22: (152, 251, 152),  # terrain
    23: (70, 130, 180),  # sky
    24: (220, 20, 60),  # person
    25: (255, 0, 0),  # rider
    26: (0, 0, 142),  # car
    32: (0, 0, 230),  # motorcycle
    33: (119, 11, 32),  # bicycle
}
_missing = sorted({label.cityscapes_id for label in LABELS} - set(CITYSCAPES_COLORS))
if _missing:
    raise RuntimeError(f"no Cityscapes colour for label ids {_missing}")
# IDDA class id -> colour of its Cityscapes label (256 entries, unknown ids black).
# RGBA with opaque alpha: Cityscapes' colour images are RGBA PNGs.
CITYSCAPES_COLOR_LUT = np.full((256, 4), 255, dtype=np.uint8)
CITYSCAPES_COLOR_LUT[: len(CITYSCAPES_ID_LUT), :3] = [CITYSCAPES_COLORS.get(int(i), (0, 0, 0)) for i in CITYSCAPES_ID_LUT]


# Cityscapes label ids with instances (helpers/labels.py hasInstances), among those the catalog maps to.
CITYSCAPES_INSTANCE_IDS = (24, 25, 26, 27, 28, 29, 30, 31, 32, 33)


def cityscapes_instance_ids(classes: np.ndarray, instance: np.ndarray | None) -> np.ndarray:
    """Cityscapes' instanceIds image: label id * 1000 + index on instance-class objects, label id elsewhere."""
    label_ids = CITYSCAPES_ID_LUT[classes]
    out = label_ids.astype(np.int32)
    if instance is None:
        return out.astype(np.uint16)
    objects = (instance > HOOD_ID) & np.isin(label_ids, CITYSCAPES_INSTANCE_IDS)
    for cs_id in np.unique(label_ids[objects]):
        ids = np.unique(instance[objects & (label_ids == cs_id)])
        for index, iid in enumerate(ids):
            out[(instance == iid) & (label_ids == cs_id)] = int(cs_id) * 1000 + index
    return out.astype(np.uint16)


def cityscapes_targets(classes: np.ndarray, instance: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """The four gtFine images of an HxW uint8 IDDA class-id image (and its instance ids)."""
    return {
        "labelIds": CITYSCAPES_ID_LUT[classes],
        "labelTrainIds": TRAIN_ID_LUT[classes],
        "color": CITYSCAPES_COLOR_LUT[classes],  # RGBA, as Cityscapes' *_gtFine_color.png
        "instanceIds": cityscapes_instance_ids(classes, instance),
    }


def cityscapes_city(scenario: str) -> str:
    """``T01-CS-A``: the city folder, equal to the file names' city prefix."""
    return scenario.replace("_", "-")


def cityscapes_name(scenario: str, episode: int, frame: int) -> str:
    """``T01-CS-A_000003_000012``: a file stem cityscapesScripts can parse."""
    return f"{cityscapes_city(scenario)}_{episode:06d}_{frame:06d}"


# Camera axes with the vehicle's orientation (x forward, y left, z up) -> OpenCV's (x right, y down, z forward).
CV_FROM_VEHICLE_AXES = np.array([[0.0, -1.0, 0.0], [0.0, 0.0, -1.0], [1.0, 0.0, 0.0]])


def cityscapes_camera(K, cam_to_ego) -> dict:
    """Cityscapes' camera JSON of a row's ``K`` and ``cam_to_ego`` (cells or matrices)."""
    K, T = as_matrix(K, 3), as_matrix(cam_to_ego, 4)
    R = T[:3, :3] @ CV_FROM_VEHICLE_AXES  # Rz(yaw) @ Ry(pitch) @ Rx(roll)
    x, y, z = T[:3, 3]
    extrinsic = {
        "baseline": 0.0,  # mono camera
        "pitch": -math.asin(max(-1.0, min(1.0, R[2, 0]))),
        "roll": math.atan2(R[2, 1], R[2, 2]),
        "x": x,
        "y": y,
        "yaw": math.atan2(R[1, 0], R[0, 0]),
        "z": z,
    }
    intrinsic = {"fx": K[0, 0], "fy": K[1, 1], "u0": K[0, 2], "v0": K[1, 2]}
    # plain floats, and 0.0 where a sign flip leaves -0.0 (the level camera's pitch): x + 0.0 is 0.0 for -0.0
    return {name: {key: float(v) + 0.0 for key, v in values.items()}
            for name, values in (("extrinsic", extrinsic), ("intrinsic", intrinsic))}


def _frame(storage, frame: ExportFrame, tmp: str, place) -> dict[str, str]:
    name = cityscapes_name(frame.scenario, frame.episode, frame.frame)
    image_dir = f"leftImg8bit/{frame.split}/{cityscapes_city(frame.scenario)}"
    gt_dir = f"gtFine/{frame.split}/{cityscapes_city(frame.scenario)}"
    rgb_rel = f"{image_dir}/{name}_leftImg8bit.png"
    rgb = frame.path("rgb")
    if is_jpeg(rgb):  # Cityscapes names PNGs: the JPEG's pixels, re-encoded losslessly
        write(os.path.join(tmp, rgb_rel), png(decode(storage, rgb, "rgb")))
    else:
        place(storage, rgb, os.path.join(tmp, rgb_rel))
    classes = decode(storage, frame.path("semantic_raw"))[..., 0]
    instance = None
    if frame.path("instance") is not None:
        instance = decode_png16(storage.read_bytes(frame.path("instance")), storage.join(frame.path("instance")))
    written = {"image": rgb_rel}
    for kind, array in cityscapes_targets(classes, instance).items():
        rel = f"{gt_dir}/{name}_gtFine_{kind}.png"
        write(os.path.join(tmp, rel), png(array))
        written[kind] = rel
    if frame.K is not None and frame.cam_to_ego is not None:  # roots written before the calibration columns lack them
        rel = f"camera/{frame.split}/{cityscapes_city(frame.scenario)}/{name}_camera.json"
        written["camera"] = write_json(tmp, rel, cityscapes_camera(frame.K, frame.cam_to_ego))
    return written


def _dirs(frames: list[ExportFrame]) -> set[str]:
    dirs = {f"{top}/{f.split}/{cityscapes_city(f.scenario)}" for f in frames for top in ("leftImg8bit", "gtFine")}
    return dirs | {f"camera/{f.split}/{cityscapes_city(f.scenario)}" for f in frames if f.K is not None}


# The cityscapes export also uses `instance` when the root holds it.
LAYOUT = Layout(outputs=("rgb", "semantic_raw"), build=per_frame(_frame, _dirs))
