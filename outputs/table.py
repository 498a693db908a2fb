"""The per-frame outputs: one table, and everything about an output derives from it.

Each :class:`Output` row names the renderer buffer it reads, the encoder that
turns that buffer into what its file holds, the file format, the decoder the
loaders apply, and a one-line description that the dataset card, docs/layout.md
and the loaders' docs show. The manifest's columns (``<output>_path / _bytes /
_sha256``), file paths, verification, queries and exports all iterate this
table.

Adding an output is one row here plus its encoder (a function in
``outputs.encoding``, or a buffer the renderer does not make yet in
``render_workers.render.episode.render_frame``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from domains.catalog import lookup
from outputs.encoding import (
    RGB_FORMATS,
    check_rgb_format,
    decode_depth_raw,
    decode_jpeg,
    decode_png,
    decode_png16,
    decode_png8,
    decode_png16rgb,
    decode_normals,
    decode_flow,
    encode_depth_gray,
    encode_depth_log,
    encode_depth_raw,
    encode_instance,
    encode_jpeg,
    encode_png,
    encode_png16,
    encode_png8,
    encode_png16rgb,
    encode_normals,
    encode_flow,
    encode_flow_clamped,
    encode_rgb,
    encode_semantic_color,
    encode_semantic_raw,
    encode_semantic_trainid,
    decode_kitti_labels,
    decode_kitti_points,
    encode_kitti_bin,
    encode_lidar_labels,
    encode_lidar_points,
)
from outputs.objects import encode_objects, objects_as_arrays, read_objects, write_objects

# The named buffers the renderer hands over per frame.
BUFFERS: dict[str, str] = {
    "rgb": "HxWx3 uint8 colour after post effects",
    "depth": "HxW float32 planar depth in metres, sky = 1000",
    "classes": "HxW uint8 class ids",
    "instance": "HxW uint16 per-episode instance ids (0 = static geometry and sky)",
    "objects": "pyarrow table of the visible objects (outputs.objects.OBJECT_SCHEMA)",
    "flow": "HxWx3 float32 forward flow to the next frame in pixels (u, v) and valid (1/0) (render_workers.render.flow)",
    "normals": "HxWx3 float32 unit surface normals, OpenCV camera frame, 0 for the sky (outputs.geometry)",
    "lidar": "a LiDAR sweep: (Nx4 float32 points, N uint32 labels) (render_workers.render.lidar)",
}


@dataclass(frozen=True)
class FileFormat:
    """How an encoded output becomes file bytes and back."""

    extension: str
    write: Callable[[Any, str], bytes]  # (content, name) -> bytes
    read: Callable[[bytes, str], Any]  # (bytes, name) -> content


FORMATS: dict[str, FileFormat] = {
    "png": FileFormat("png", encode_png, decode_png),  # HxWx3 uint8 RGB
    "png16": FileFormat("png", encode_png16, decode_png16),  # HxW uint16
    "png8": FileFormat("png", encode_png8, decode_png8),  # HxW uint8 (grey)
    "png16rgb": FileFormat("png", encode_png16rgb, decode_png16rgb),  # HxWx3 uint16
    "jpg": FileFormat("jpg", encode_jpeg, decode_jpeg),  # HxWx3 uint8 RGB, lossy (the rgb output's option)
    "parquet": FileFormat("parquet", write_objects, read_objects),  # a table
    "bin": FileFormat("bin", encode_kitti_bin, decode_kitti_points),  # SemanticKITTI points, Nx4 float32
    "label": FileFormat("label", encode_kitti_bin, decode_kitti_labels),  # SemanticKITTI labels, N uint32
}


def _first_channel(image: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(image[..., 0])


def _depth_metres(image: np.ndarray) -> np.ndarray:
    return decode_depth_raw(image).astype(np.float32)


def _same(content):
    return content


@dataclass(frozen=True)
class Output:
    name: str  # directory name and manifest column prefix
    source: str  # the renderer buffer it reads (BUFFERS)
    encode: Callable[[Any], Any]  # buffer -> file content; checks dtype and shape
    file: str  # FORMATS key
    decode: Callable[[Any], Any]  # file content -> the array a loader returns
    key: str  # the loaders' sample key
    dtype: str  # dtype of the loaders' array ("table" for a sidecar)
    channels: int  # channels of the loaders' array (0 for a sidecar)
    description: str  # one line for the card, docs/layout.md and the loaders' docs
    other_files: tuple[str, ...] = ()  # FORMATS keys a root may choose instead of ``file`` (rgb: --rgb-format)

    @property
    def format(self) -> FileFormat:
        return FORMATS[self.file]

    @property
    def extension(self) -> str:
        return self.format.extension

    @property
    def files(self) -> tuple[str, ...]:
        """Every FORMATS key this output can be written in, the default first."""
        return (self.file,) + self.other_files

    def file_in(self, rgb_format: str = "png") -> str:
        """The FORMATS key of this output in a root whose rgb format is ``rgb_format``."""
        return rgb_format if check_rgb_format(rgb_format) in self.other_files else self.file


OUTPUT_TABLE: tuple[Output, ...] = (
    Output("rgb", "rgb", encode_rgb, "png", _same, "rgb", "uint8", 3,
           "lit colour image with bloom, lens flare, motion blur and weather grading", other_files=("jpg",)),
    Output("depth_raw", "depth", encode_depth_raw, "png", _depth_metres, "depth", "float32", 1,
           "planar depth, 24 bits in R, G, B: `depth_m = 1000 * (R + G*256 + B*65536) / (256**3 - 1)`; sky = 1000 m"),
    Output("depth_gray", "depth", encode_depth_gray, "png", _first_channel, "depth_gray", "uint8", 1,
           "`255 * depth_m / 1000` (linear, dark up close)"),
    Output("depth_log", "depth", encode_depth_log, "png", _first_channel, "depth_log", "uint8", 1,
           "`255 * clamp(1 + ln(depth_m / 1000) / ln(300), 0, 1)`"),
    Output("semantic_raw", "classes", encode_semantic_raw, "png", _first_channel, "semantic", "uint8", 1,
           "class id in the red channel (G = B = 0)"),
    Output("semantic_color", "classes", encode_semantic_color, "png", _same, "semantic_color", "uint8", 3,
           "class colours (the paper's palette)"),
    Output("instance", "instance", encode_instance, "png16", _same, "instance", "uint16", 1,
           "16-bit instance ids, stable over an episode: one per vehicle, pedestrian, rider, bicycle, motorcycle, "
           "traffic light and sign; the hood has its own; static geometry and sky 0"),
    Output("objects", "objects", encode_objects, "parquet", objects_as_arrays, "objects", "table", 0,
           "Parquet, one row per visible object: instance id, class, tight 2D box, visible pixels, occlusion, "
           "truncation, 3D box (centre, size, yaw) in the OpenCV camera frame of the row's `cam_to_world` "
           "(x right, y down, z forward; docs/conventions.md)"),
    # Opt-in outputs (not in DEFAULT_OUTPUTS): ask for them with --outputs.
    Output("semantic_trainid", "classes", encode_semantic_trainid, "png8", _same, "semantic_trainid", "uint8", 1,
           "8-bit grey: the Cityscapes trainId (0-18) of the pixel's class, 255 = ignore (as `*_labelTrainIds.png`)"),
    Output("normals", "normals", encode_normals, "png16rgb", decode_normals, "normals", "float32", 3,
           "16-bit RGB: unit surface normal in the OpenCV camera frame (x right, y down, z forward), facing the "
           "camera, `n = RGB / 65535 * 2 - 1`; (0, 0, 0) = no surface (sky)"),
    Output("flow", "flow", encode_flow, "png16rgb", decode_flow, "flow", "float32", 3,
           "16-bit RGB, KITTI's flow encoding: forward flow to the episode's next frame from geometry and object "
           "motion, `u = (R - 2**15) / 64`, `v = (G - 2**15) / 64`, B = 1 where valid (0 for the last frame, the sky, "
           "points whose next position is out of view and motion beyond the encoding's +-512 px)"),
    # A rig's LiDAR writes these (never asked for with --outputs): docs/conventions.md, "Sensor rigs".
    Output("lidar_points", "lidar", encode_lidar_points, "bin", _same, "lidar_points", "float32", 0,
           "SemanticKITTI `.bin`: float32 x, y, z (the LiDAR's frame: x forward, y left, z up, metres), intensity (0)"),
    Output("lidar_labels", "lidar", encode_lidar_labels, "label", _same, "lidar_labels", "uint32", 0,
           "SemanticKITTI `.label`: uint32 per point, class id in the low 16 bits, instance id in the high 16"),
)
# The encoders of roots made before rules (manifests.schema.OLD_RULES) where they differ, so such a root
# keeps writing what it holds: docs/layout.md, "Rules of a root".
OLD_RULE_ENCODERS: dict[str, Callable] = {"flow": encode_flow_clamped}
OUTPUT_BY_NAME: dict[str, Output] = {o.name: o for o in OUTPUT_TABLE}
OUTPUTS: tuple[str, ...] = tuple(OUTPUT_BY_NAME)
SEED_OUTPUTS: tuple[str, ...] = OUTPUTS[:6]  # the six images of the IDDA paper
# what `idda produce` writes unless --outputs says otherwise: the paper's six, instance and objects
DEFAULT_OUTPUTS: tuple[str, ...] = OUTPUTS[:8]
IMAGE_OUTPUTS: tuple[str, ...] = tuple(o.name for o in OUTPUT_TABLE if o.channels)
LIDAR_OUTPUTS: tuple[str, ...] = tuple(o.name for o in OUTPUT_TABLE if o.source == "lidar")
CAMERA_OUTPUTS: tuple[str, ...] = tuple(o for o in OUTPUTS if o not in LIDAR_OUTPUTS)  # what --outputs may ask for

for _output in OUTPUT_TABLE:  # every row reads a known buffer and writes known formats
    lookup(BUFFERS, _output.source, "buffer")
    for _file in _output.files:
        lookup(FORMATS, _file, "file format")
del _output, _file
# --rgb-format picks the rgb output's file: every choice but the default is one of its other files.
assert set(RGB_FORMATS[1:]) <= set(OUTPUT_TABLE[0].other_files) and OUTPUT_TABLE[0].file == RGB_FORMATS[0]


def output(name: str) -> Output:
    """The table row of an output; ValueError lists the valid names."""
    return lookup(OUTPUT_BY_NAME, name, "output")


def check_outputs(names) -> tuple[str, ...]:
    """A validated, de-duplicated selection of outputs in table order."""
    names = tuple(names)
    if not names:
        raise ValueError(f"ask for at least one output; valid outputs: {', '.join(OUTPUTS)}")
    for name in names:
        output(name)
        if name in LIDAR_OUTPUTS:
            raise ValueError(f"output {name!r} is written by a rig's LiDAR (--rig lidar64), not asked for; "
                             f"valid outputs: {', '.join(CAMERA_OUTPUTS)}")
    return tuple(o for o in OUTPUTS if o in names)


def parse_outputs(text: str) -> tuple[str, ...]:
    """``"rgb,instance"`` -> a validated selection (see :func:`check_outputs`)."""
    return check_outputs(n.strip() for n in text.split(",") if n.strip())


def encode_outputs(buffers: dict[str, Any], names: tuple[str, ...] = DEFAULT_OUTPUTS,
                   old_rules: bool = False) -> dict[str, Any]:
    """The requested outputs' file contents from the renderer's named buffers; ``old_rules``: as a root
    made before rules writes them (OLD_RULE_ENCODERS)."""
    shapes = {k: v.shape[:2] for k, v in buffers.items() if isinstance(v, np.ndarray) and v.ndim >= 2}
    if len(set(shapes.values())) > 1:
        raise ValueError(f"buffers disagree in size: {shapes}")
    out = {}
    for name in names:
        row = output(name)
        if row.source not in buffers:
            raise ValueError(f"output {name!r} needs the {row.source!r} buffer, which this frame lacks")
        encode = OLD_RULE_ENCODERS.get(name, row.encode) if old_rules else row.encode
        out[name] = encode(buffers[row.source])
    return out


def extension(name: str, rgb_format: str = "png") -> str:
    """The file extension of output ``name`` in a root whose rgb format is ``rgb_format``."""
    return FORMATS[output(name).file_in(rgb_format)].extension


def file_bytes(name: str, content, rgb_format: str = "png") -> bytes:
    """The bytes of one output's file (in a root whose rgb format is ``rgb_format``)."""
    return FORMATS[output(name).file_in(rgb_format)].write(content, name)


def file_of_path(name: str, path: str) -> str:
    """The FORMATS key of output ``name``'s file at ``path`` (by its extension; the default otherwise)."""
    row = output(name)
    for file in row.other_files:
        if path.endswith("." + FORMATS[file].extension):
            return file
    return row.file


def read_output(name: str, data: bytes, where: str = "") -> Any:
    """One output's file content from its bytes (an image array or a table); ``where`` is its
    path (or URI), whose extension tells the rgb output's PNG from its JPEG."""
    return FORMATS[file_of_path(name, where)].read(data, where or name)


def markdown_table(names: tuple[str, ...] = OUTPUTS, rgb_format: str | None = None) -> list[str]:
    """The outputs as a Markdown table (the card and docs/layout.md show it). With ``rgb_format``
    None the file column lists every choice; with one, the root's."""
    def files(o: Output) -> str:
        if rgb_format is not None:
            return o.file_in(rgb_format)
        return o.file + "".join(f" (or {f}: `--rgb-format {f}`)" for f in o.other_files)

    lines = ["| output | file | content |", "|---|---|---|"]
    lines += [f"| `{o.name}` | {files(o)} | {o.description} |" for o in OUTPUT_TABLE if o.name in names]
    return lines
