"""Per-frame output encodings (CARLA conventions) and PNG bytes, in pure numpy + cv2.

Each output in ``manifests.outputs.OUTPUT_TABLE`` names one of these encoders,
which turns one of the renderer's buffers into the array its file holds:

* ``rgb``: the post-processed colour image, passed through;
* ``depth_raw``: ``v = round(depth/1000 * (256**3-1))`` spread over R, G, B
  (R least significant), decoded by :func:`decode_depth_raw`;
* ``depth_gray``: ``round(depth/1000 * 255)`` (CARLA ``Depth``);
* ``depth_log``: ``round(clamp(1 + ln(n)/ln(300), 0, 1) * 255)`` with
  ``n = depth/1000`` and 0 for n = 0 (CARLA ``LogarithmicDepth``);
* ``semantic_raw``: the class id in R, G = B = 0;
* ``semantic_color``: ``PALETTE[class id]``;
* ``instance``: the per-episode instance ids, HxW uint16 (a 16-bit PNG).

Depth is metric planar Z (float, metres) with background/sky at 1000 m.

This is part of the dataset's vocabulary: the renderer encodes with it, and
exports, loaders and verification decode with it.
"""

from __future__ import annotations

import numpy as np

from manifests.catalog import NUM_CLASSES, PALETTE

FAR_M = 1000.0  # depth far limit; sky and background count as this
DEPTH_LEVELS = 256**3 - 1
DEPTH_STEP_M = FAR_M / DEPTH_LEVELS  # one depth_raw quantisation step
LOG_DEPTH_SCALE = 5.70378  # ln(300): the log ramp covers ~3.33 m .. 1000 m
PNG_COMPRESSION = 1  # zlib level: fast; PNG stays lossless and deterministic

def _check(name: str, array: np.ndarray, dtype, ndim: int) -> None:
    if not isinstance(array, np.ndarray):
        raise ValueError(f"{name}: expected a numpy array, got {type(array).__name__}")
    if array.ndim != ndim or (ndim == 3 and array.shape[2] != 3):
        want = "HxWx3" if ndim == 3 else "HxW"
        raise ValueError(f"{name}: expected an {want} array, got shape {array.shape}")
    if np.dtype(dtype).kind == "f":
        if array.dtype.kind != "f":
            raise ValueError(f"{name}: expected a float array, got {array.dtype}")
    elif array.dtype != dtype:
        raise ValueError(f"{name}: expected dtype {np.dtype(dtype)}, got {array.dtype}")


def _normalised_depth(depth: np.ndarray, name: str) -> np.ndarray:
    _check(name, depth, np.float64, 2)
    if np.isnan(depth).any():
        raise ValueError(f"{name}: depth contains NaN")
    return np.clip(depth.astype(np.float64) / FAR_M, 0.0, 1.0)


def _gray3(values: np.ndarray) -> np.ndarray:
    return np.repeat(values.astype(np.uint8)[:, :, None], 3, axis=2)


def encode_rgb(rgb: np.ndarray) -> np.ndarray:
    _check("rgb", rgb, np.uint8, 3)
    return rgb


def encode_depth_raw(depth: np.ndarray) -> np.ndarray:
    n = _normalised_depth(depth, "depth_raw")
    v = np.rint(n * DEPTH_LEVELS).astype(np.uint32)
    out = np.empty(v.shape + (3,), dtype=np.uint8)
    out[..., 0] = v & 255
    out[..., 1] = (v >> 8) & 255
    out[..., 2] = (v >> 16) & 255
    return out


def decode_depth_raw(image: np.ndarray) -> np.ndarray:
    """Metric depth (float64, metres) from a ``depth_raw`` RGB image."""
    _check("depth_raw", image, np.uint8, 3)
    v = image.astype(np.uint32)
    return FAR_M * (v[..., 0] + v[..., 1] * 256 + v[..., 2] * 65536) / DEPTH_LEVELS


def encode_depth_gray(depth: np.ndarray) -> np.ndarray:
    n = _normalised_depth(depth, "depth_gray")
    return _gray3(np.rint(n * 255.0))


def encode_depth_log(depth: np.ndarray) -> np.ndarray:
    n = _normalised_depth(depth, "depth_log")
    with np.errstate(divide="ignore"):
        v = np.clip(1.0 + np.log(n) / LOG_DEPTH_SCALE, 0.0, 1.0)  # log(0) = -inf -> 0
    return _gray3(np.rint(v * 255.0))


def _check_classes(classes: np.ndarray, name: str) -> None:
    _check(name, classes, np.uint8, 2)
    if classes.size and int(classes.max()) >= NUM_CLASSES:
        raise ValueError(f"{name}: class id {int(classes.max())} is not below {NUM_CLASSES}")


def encode_semantic_raw(classes: np.ndarray) -> np.ndarray:
    _check_classes(classes, "semantic_raw")
    out = np.zeros(classes.shape + (3,), dtype=np.uint8)
    out[..., 0] = classes
    return out


def encode_semantic_color(classes: np.ndarray) -> np.ndarray:
    _check_classes(classes, "semantic_color")
    return PALETTE[classes]


def encode_png(image: np.ndarray, name: str = "image") -> bytes:
    """Lossless, deterministic PNG bytes of an HxWx3 uint8 RGB image."""
    import cv2

    _check(name, image, np.uint8, 3)
    bgr = cv2.cvtColor(np.ascontiguousarray(image), cv2.COLOR_RGB2BGR)
    ok, buf = cv2.imencode(".png", bgr, [cv2.IMWRITE_PNG_COMPRESSION, PNG_COMPRESSION])
    if not ok:
        raise ValueError(f"{name}: PNG encoding failed for shape {image.shape}")
    return buf.tobytes()


def decode_png(data: bytes, name: str = "image") -> np.ndarray:
    """HxWx3 uint8 RGB image from PNG bytes."""
    import cv2

    image = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_COLOR)
    if image is None:
        raise ValueError(f"{name}: not a decodable PNG ({len(data)} bytes)")
    return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


def encode_instance(instances: np.ndarray) -> np.ndarray:
    """Instance ids as they are stored: HxW uint16 (0 = no object)."""
    _check("instance", instances, np.uint16, 2)
    return instances


def encode_png16(image: np.ndarray, name: str = "image") -> bytes:
    """Lossless, deterministic 16-bit single-channel PNG bytes of an HxW uint16 image."""
    import cv2

    _check(name, image, np.uint16, 2)
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(image), [cv2.IMWRITE_PNG_COMPRESSION, PNG_COMPRESSION])
    if not ok:
        raise ValueError(f"{name}: PNG encoding failed for shape {image.shape}")
    return buf.tobytes()


def decode_png16(data: bytes, name: str = "image") -> np.ndarray:
    """HxW uint16 image from 16-bit single-channel PNG bytes."""
    import cv2

    image = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise ValueError(f"{name}: not a decodable PNG ({len(data)} bytes)")
    if image.dtype != np.uint16 or image.ndim != 2:
        raise ValueError(f"{name}: expected a 16-bit single-channel PNG, got {image.dtype} {image.shape}")
    return image
