"""Per-frame output encodings (CARLA conventions) and PNG bytes, in numpy + zlib-ng (cv2 decodes).

Each output in ``outputs.table.OUTPUT_TABLE`` names one of these encoders,
which turns one of the renderer's buffers into the array its file holds:

* ``rgb``: the post-processed colour image, passed through;
* ``depth_raw``: ``v = round(depth/1000 * (256**3-1))`` spread over R, G, B
  (R least significant), decoded by :func:`decode_depth_raw`;
* ``depth_gray``: ``round(depth/1000 * 255)`` (CARLA ``Depth``);
* ``depth_log``: ``round(clamp(1 + ln(n)/ln(300), 0, 1) * 255)`` with
  ``n = depth/1000`` and 0 for n = 0 (CARLA ``LogarithmicDepth``);
* ``semantic_raw``: the class id in R, G = B = 0;
* ``semantic_color``: ``PALETTE[class id]``;
* ``instance``: the per-episode instance ids, HxW uint16 (a 16-bit PNG);
* ``semantic_trainid`` (opt-in): the Cityscapes trainId of each pixel's class
  (``catalog.TRAIN_ID_LUT``, 255 = ignore), HxW uint8 (an 8-bit grey PNG, as
  Cityscapes' ``*_labelTrainIds.png``).

Depth is metric planar Z (float, metres) with background/sky at 1000 m.

This is part of the dataset's vocabulary: the renderer encodes with it, and
exports, loaders and verification decode with it.

PNG files are written here, not by a codec library: every row gets PNG filter
1 (Sub, in numpy) and the image is one IDAT deflated by zlib-ng, a photograph
(:data:`PHOTO_OUTPUTS`) with run-length matches only (``outputs.deflaters``; roots
written before keep the deflater they were made with). Skipping libpng's adaptive per-row filter choice, most of its
cost, makes this several times faster than OpenCV's PNG writer. Any PNG reader
decodes the files; a different deflater (or version) gives different bytes,
so the run record names it (:func:`encoder_identity`).

The ``rgb`` output may instead be a JPEG (``--rgb-format jpg``, the format of
the released IDDA RGB images): quality :data:`JPEG_QUALITY`, 4:2:0 chroma,
encoded by libjpeg-turbo as OpenCV's wheel bundles it (:func:`encode_jpeg`;
on a full-HD T01_CN_A frame 256 KB and 4.6 ms of CPU against the PNG's 915 KB
and 8.0 ms). It is deterministic for one OpenCV build, so the run record names
that build too.
"""

from __future__ import annotations

import struct
import zlib
from functools import cache

import numpy as np

from domains.catalog import NUM_CLASSES, PALETTE, TRAIN_ID_LUT
from outputs.deflaters import DEFAULT_DEFLATER, deflate_png_data, deflater

FAR_M = 1000.0  # depth far limit; sky and background count as this
DEPTH_LEVELS = 256**3 - 1
DEPTH_STEP_M = FAR_M / DEPTH_LEVELS  # one depth_raw quantisation step
LOG_DEPTH_SCALE = 5.70378  # ln(300): the log ramp covers ~3.33 m .. 1000 m
JPEG_QUALITY = 95  # the released IDDA RGB images' quality
JPEG_ENCODER = "jpeg-libjpeg-turbo-opencv"  # cv2.imencode: libjpeg-turbo, 4:2:0, baseline Huffman
RGB_FORMATS = ("png", "jpg")  # file formats of the rgb output; the first is the default
# Outputs whose PNG rows are a photograph (continuous tone after post effects: runs, few repeats), which the
# deflater may treat apart (outputs.deflaters: run-length matches only). Chosen by the output's name.
PHOTO_OUTPUTS = frozenset({"rgb"})

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


def _normalised_depth(depth: np.ndarray, name: str, dtype=np.float64) -> np.ndarray:
    _check(name, depth, np.float64, 2)
    if np.isnan(depth).any():
        raise ValueError(f"{name}: depth contains NaN")
    n = np.multiply(depth, dtype(1.0 / FAR_M), dtype=dtype)
    return np.clip(n, 0.0, 1.0, out=n)


def _gray3(unit: np.ndarray) -> np.ndarray:
    """round(unit * 255) (unit: float32 in [0, 1], rounding half to even like np.rint) as HxWx3 uint8."""
    import cv2

    return cv2.cvtColor(cv2.convertScaleAbs(unit, alpha=255.0), cv2.COLOR_GRAY2RGB)


def encode_rgb(rgb: np.ndarray) -> np.ndarray:
    _check("rgb", rgb, np.uint8, 3)
    return rgb


def encode_depth_raw(depth: np.ndarray) -> np.ndarray:
    import cv2

    n = _normalised_depth(depth, "depth_raw")  # float64: 24 bits need more than float32 keeps
    # n * levels rounded half to even (np.rint's rounding; OpenCV's double-to-int conversion rounds so),
    # as int32 in one pass, then its three low bytes (little-endian: R = lowest byte): 4 ms, not 14
    v = cv2.multiply(n, float(DEPTH_LEVELS), dtype=cv2.CV_32S).astype("<i4", copy=False)
    return cv2.cvtColor(v.view(np.uint8).reshape(v.shape + (4,)), cv2.COLOR_RGBA2RGB)


def decode_depth_raw(image: np.ndarray) -> np.ndarray:
    """Metric depth (float64, metres) from a ``depth_raw`` RGB image."""
    _check("depth_raw", image, np.uint8, 3)
    v = image.astype(np.uint32)
    return FAR_M * (v[..., 0] + v[..., 1] * 256 + v[..., 2] * 65536) / DEPTH_LEVELS


def encode_depth_gray(depth: np.ndarray) -> np.ndarray:
    return _gray3(_normalised_depth(depth, "depth_gray", np.float32))


def encode_depth_log(depth: np.ndarray) -> np.ndarray:
    import cv2

    n = _normalised_depth(depth, "depth_log", np.float32)
    # cv2.log(0) is a large negative number rather than -inf: the clip sends both to 0
    return _gray3(np.clip(cv2.log(n) * np.float32(1.0 / LOG_DEPTH_SCALE) + np.float32(1.0), 0.0, 1.0))


def _check_classes(classes: np.ndarray, name: str) -> None:
    _check(name, classes, np.uint8, 2)
    if classes.size and int(classes.max()) >= NUM_CLASSES:
        raise ValueError(f"{name}: class id {int(classes.max())} is not below {NUM_CLASSES}")


def encode_semantic_raw(classes: np.ndarray) -> np.ndarray:
    _check_classes(classes, "semantic_raw")
    out = np.zeros(classes.shape + (3,), dtype=np.uint8)
    out[..., 0] = classes
    return out


_PALETTE_LUT = np.zeros((256, 1, 3), np.uint8)  # cv2.LUT table: class id -> palette colour, per channel
_PALETTE_LUT[: len(PALETTE), 0] = PALETTE


def encode_semantic_color(classes: np.ndarray) -> np.ndarray:
    import cv2

    _check_classes(classes, "semantic_color")
    return cv2.LUT(cv2.cvtColor(classes, cv2.COLOR_GRAY2RGB), _PALETTE_LUT)


_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_PNG_COLOUR_TYPE = {1: 0, 3: 2, 4: 6}  # channels -> grey, RGB, RGBA


def _png_chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))


def _sub_filtered(rows: np.ndarray, bpp: int) -> np.ndarray:
    """PNG scanlines with filter type 1 (Sub): each byte minus the one ``bpp`` bytes left, mod 256."""
    out = np.empty((rows.shape[0], rows.shape[1] + 1), np.uint8)
    out[:, 0] = 1
    out[:, 1:bpp + 1] = rows[:, :bpp]
    np.subtract(rows[:, bpp:], rows[:, :-bpp], out=out[:, bpp + 1:])
    return out


def png_bytes(image: np.ndarray, name: str = "image") -> bytes:
    """Lossless, deterministic PNG bytes of an HxW (grey), HxWx3 (RGB) or HxWx4 (RGBA) image, uint8 or uint16,
    deflated by the deflater in force (``outputs.deflaters.deflating_with``); ``name``: the output's (one
    of PHOTO_OUTPUTS is deflated as a photograph) or a name for messages."""
    if not isinstance(image, np.ndarray) or image.dtype not in (np.uint8, np.uint16):
        raise ValueError(f"{name}: expected a uint8 or uint16 numpy array, got {getattr(image, 'dtype', type(image))}")
    channels = 1 if image.ndim == 2 else (image.shape[2] if image.ndim == 3 else 0)
    if channels not in _PNG_COLOUR_TYPE or image.shape[0] < 1 or image.shape[1] < 1:
        raise ValueError(f"{name}: expected an HxW, HxWx3 or HxWx4 image, got shape {image.shape}")
    height, width = image.shape[:2]
    depth = image.dtype.itemsize * 8
    big_endian = image.astype(">u2", copy=False) if depth == 16 else image
    rows = np.ascontiguousarray(big_endian).view(np.uint8).reshape(height, -1)
    data = deflate_png_data(_sub_filtered(rows, channels * image.dtype.itemsize), name in PHOTO_OUTPUTS)
    header = struct.pack(">IIBBBBB", width, height, depth, _PNG_COLOUR_TYPE[channels], 0, 0, 0)
    return _PNG_SIGNATURE + _png_chunk(b"IHDR", header) + _png_chunk(b"IDAT", data) + _png_chunk(b"IEND", b"")


def encode_png(image: np.ndarray, name: str = "image") -> bytes:
    """Lossless, deterministic PNG bytes of an HxWx3 uint8 RGB image."""
    _check(name, image, np.uint8, 3)
    return png_bytes(image, name)


def encode_jpeg(image: np.ndarray, name: str = "image", quality: int = JPEG_QUALITY) -> bytes:
    """JPEG bytes (baseline, 4:2:0) of an HxWx3 uint8 RGB image; deterministic for one OpenCV build."""
    import cv2

    _check(name, image, np.uint8, 3)
    ok, buf = cv2.imencode(".jpg", cv2.cvtColor(image, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise ValueError(f"{name}: JPEG encoding failed for an image of shape {image.shape}")
    return buf.tobytes()


def check_rgb_format(rgb_format: str) -> str:
    if rgb_format not in RGB_FORMATS:
        raise ValueError(f"unknown rgb format {rgb_format!r}; valid formats: {', '.join(RGB_FORMATS)}")
    return rgb_format


@cache
def encoder_identity(rgb_format: str = "png", png_deflater: str = DEFAULT_DEFLATER) -> str:
    """What makes the files' bytes: the PNG deflater, its level and its package's version;
    with JPEG rgb files also the JPEG encoder, its quality and the OpenCV build."""
    png = deflater(png_deflater).identity
    if check_rgb_format(rgb_format) == "png":
        return png
    import cv2

    return f"{png}; rgb {JPEG_ENCODER} quality {JPEG_QUALITY}, opencv {cv2.__version__}"


def _decode_colour(data: bytes, name: str, kind: str) -> np.ndarray:
    import cv2

    image = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_COLOR)
    if image is None:
        raise ValueError(f"{name}: not a decodable {kind} ({len(data)} bytes)")
    return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


def decode_png(data: bytes, name: str = "image") -> np.ndarray:
    """HxWx3 uint8 RGB image from PNG bytes."""
    return _decode_colour(data, name, "PNG")


def decode_jpeg(data: bytes, name: str = "image") -> np.ndarray:
    """HxWx3 uint8 RGB image from JPEG bytes."""
    return _decode_colour(data, name, "JPEG")


def encode_semantic_trainid(classes: np.ndarray) -> np.ndarray:
    """Cityscapes trainIds (19 classes, 255 = ignore) of a class-id image: HxW uint8."""
    _check_classes(classes, "semantic_trainid")
    return TRAIN_ID_LUT[classes]


def encode_png8(image: np.ndarray, name: str = "image") -> bytes:
    """Lossless, deterministic 8-bit single-channel (grey) PNG bytes of an HxW uint8 image."""
    _check(name, image, np.uint8, 2)
    return png_bytes(image, name)


def decode_png8(data: bytes, name: str = "image") -> np.ndarray:
    """HxW uint8 image from 8-bit single-channel PNG bytes."""
    return _decode_single(data, name, np.uint8)


def encode_normals(normals: np.ndarray) -> np.ndarray:
    """Unit normals (HxWx3 float, camera frame) as stored: ``round((n + 1) / 2 * 65535)`` per
    component, HxWx3 uint16; no surface (a zero vector) is stored as (0, 0, 0)."""
    _check("normals", normals, np.float32, 3)
    n = np.asarray(normals, dtype=np.float64)
    out = np.rint((np.clip(n, -1.0, 1.0) + 1.0) * (65535 / 2.0)).astype(np.uint16)
    out[~n.any(axis=-1)] = 0
    return out


def decode_normals(image: np.ndarray) -> np.ndarray:
    """HxWx3 float32 normals from a ``normals`` file's uint16 RGB image; (0, 0, 0) stays a zero vector."""
    n = image.astype(np.float32) * np.float32(2.0 / 65535) - np.float32(1.0)
    n[~image.any(axis=-1)] = 0.0
    return n


FLOW_SCALE = 64.0  # KITTI's: 1/64 px steps around 2**15, so u and v in [-512, 511.984375] px


def _flow_steps(flow: np.ndarray) -> np.ndarray:
    return np.rint(flow[..., :2].astype(np.float64) * FLOW_SCALE + 2**15)


def encode_flow(flow: np.ndarray) -> np.ndarray:
    """KITTI's flow encoding of an HxWx3 float (u, v, valid) buffer: ``R = u * 64 + 2**15``,
    ``G = v * 64 + 2**15``, ``B = 1`` where valid; invalid pixels are (0, 0, 0). A motion the 16 bits
    cannot hold (u or v beyond [-512, 511.984375] px, e.g. near the image's sides at full HD and
    3 s between frames) is invalid too: never clamped and kept."""
    _check("flow", flow, np.float32, 3)
    steps = _flow_steps(flow)
    valid = (flow[..., 2] > 0) & ((steps >= 0) & (steps <= 65535)).all(axis=-1)
    out = np.zeros(flow.shape, np.uint16)
    out[valid, :2] = steps[valid]
    out[..., 2] = valid
    return out


def encode_flow_clamped(flow: np.ndarray) -> np.ndarray:
    """``encode_flow`` as roots made before rules (manifests.schema.OLD_RULES) keep it: a motion beyond
    the 16-bit range is clamped to +-512 px and stays valid."""
    _check("flow", flow, np.float32, 3)
    valid = flow[..., 2] > 0
    out = np.zeros(flow.shape, np.uint16)
    out[..., :2] = np.clip(_flow_steps(flow), 0, 65535)
    out[..., 2] = valid
    out[~valid] = 0
    return out


def decode_flow(image: np.ndarray) -> np.ndarray:
    """HxWx3 float32 (u, v, valid) from a ``flow`` file's uint16 RGB image (KITTI's encoding)."""
    out = (image.astype(np.float32) - np.float32(2**15)) / np.float32(FLOW_SCALE)
    out[..., 2] = image[..., 2] > 0
    out[image[..., 2] == 0, :2] = 0.0
    return out


def encode_png16rgb(image: np.ndarray, name: str = "image") -> bytes:
    """Lossless, deterministic 16-bit RGB PNG bytes of an HxWx3 uint16 image."""
    _check(name, image, np.uint16, 3)
    return png_bytes(image, name)


def decode_png16rgb(data: bytes, name: str = "image") -> np.ndarray:
    """HxWx3 uint16 RGB image from 16-bit RGB PNG bytes."""
    import cv2

    image = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None or image.dtype != np.uint16 or image.ndim != 3 or image.shape[2] != 3:
        raise ValueError(f"{name}: expected a 16-bit RGB PNG ({len(data)} bytes)")
    return cv2.cvtColor(image, cv2.COLOR_BGR2RGB)


def encode_instance(instances: np.ndarray) -> np.ndarray:
    """Instance ids as they are stored: HxW uint16 (0 = no object)."""
    _check("instance", instances, np.uint16, 2)
    return instances


def encode_png16(image: np.ndarray, name: str = "image") -> bytes:
    """Lossless, deterministic 16-bit single-channel PNG bytes of an HxW uint16 image."""
    _check(name, image, np.uint16, 2)
    return png_bytes(image, name)


def decode_png16(data: bytes, name: str = "image") -> np.ndarray:
    """HxW uint16 image from 16-bit single-channel PNG bytes."""
    return _decode_single(data, name, np.uint16)


def _decode_single(data: bytes, name: str, dtype) -> np.ndarray:
    """HxW image of ``dtype`` (uint8 or uint16) from single-channel PNG bytes of that depth."""
    import cv2

    image = cv2.imdecode(np.frombuffer(data, dtype=np.uint8), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise ValueError(f"{name}: not a decodable PNG ({len(data)} bytes)")
    if image.dtype != dtype or image.ndim != 2:
        bits = np.dtype(dtype).itemsize * 8
        article = "an" if bits == 8 else "a"
        raise ValueError(f"{name}: expected {article} {bits}-bit single-channel PNG, got {image.dtype} {image.shape}")
    return image


# ------------------------------------------------------------ LiDAR (SemanticKITTI's files) ----
def encode_lidar_points(sweep) -> np.ndarray:
    """A sweep's (points, labels) -> its points: Nx4 float32 x, y, z (sensor frame, metres), intensity."""
    points, labels = sweep
    _check("lidar_points", points, np.float32, 2)
    if points.shape[1:] != (4,) or labels.shape != (len(points),):
        raise ValueError(f"lidar_points: expected Nx4 points and N labels, got {points.shape} and {labels.shape}")
    return points


def encode_lidar_labels(sweep) -> np.ndarray:
    """A sweep's (points, labels) -> its labels: N uint32, class id in the low 16 bits, instance id in the high 16."""
    points, labels = sweep
    _check("lidar_labels", labels, np.uint32, 1)
    return labels


def encode_kitti_bin(array: np.ndarray, name: str = "points") -> bytes:
    """SemanticKITTI's ``.bin``/``.label`` bytes: the array's little-endian values, row-major, no header."""
    if array.dtype not in (np.float32, np.uint32):
        raise ValueError(f"{name}: expected float32 or uint32 values, got {array.dtype}")
    return np.ascontiguousarray(array, dtype=array.dtype.newbyteorder("<")).tobytes()


def decode_kitti_points(data: bytes, name: str = "points") -> np.ndarray:
    """Nx4 float32 (x, y, z, intensity) from a ``.bin`` file's bytes."""
    if len(data) % 16:
        raise ValueError(f"{name}: {len(data)} bytes is not a whole number of 16-byte points")
    return np.frombuffer(data, dtype="<f4").reshape(-1, 4).astype(np.float32)


def decode_kitti_labels(data: bytes, name: str = "labels") -> np.ndarray:
    """N uint32 labels from a ``.label`` file's bytes."""
    if len(data) % 4:
        raise ValueError(f"{name}: {len(data)} bytes is not a whole number of 4-byte labels")
    return np.frombuffer(data, dtype="<u4").astype(np.uint32)
