"""Encoders: CARLA depth/semantic encodings and PNG bytes, as tiny arrays and properties."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from domains.catalog import NUM_CLASSES, PALETTE
from outputs import encoding as enc
from outputs import table as out_table
from outputs.table import OUTPUTS, SEED_OUTPUTS

depths = hnp.arrays(
    np.float32, hnp.array_shapes(min_dims=2, max_dims=2, min_side=1, max_side=12),
    elements=st.floats(0.0, 1000.0, width=32),
)
class_maps = hnp.arrays(
    np.uint8, hnp.array_shapes(min_dims=2, max_dims=2, min_side=1, max_side=12),
    elements=st.integers(0, NUM_CLASSES - 1),
)
images = hnp.arrays(np.uint8, st.tuples(st.integers(1, 16), st.integers(1, 16), st.just(3)))


def test_output_table_names_are_unique_and_known():
    assert len(set(OUTPUTS)) == len(OUTPUTS) == 13
    assert out_table.LIDAR_OUTPUTS == ("lidar_points", "lidar_labels") and len(out_table.CAMERA_OUTPUTS) == 11
    assert OUTPUTS[:6] == SEED_OUTPUTS
    assert out_table.DEFAULT_OUTPUTS == SEED_OUTPUTS + ("instance", "objects")  # new outputs are opt-in
    with pytest.raises(ValueError, match="valid outputs"):
        out_table.output("depth_fancy")
    with pytest.raises(ValueError, match="valid outputs"):
        out_table.parse_outputs("rgb,depth_fancy")
    assert out_table.parse_outputs("instance, rgb,rgb") == ("rgb", "instance")


def test_depth_raw_known_values():
    depth = np.array([[0.0, 1000.0, 500.0]], dtype=np.float32)
    raw = enc.encode_depth_raw(depth)
    assert raw[0, 0].tolist() == [0, 0, 0]
    assert raw[0, 1].tolist() == [255, 255, 255]
    v = round(0.5 * (256**3 - 1))
    assert raw[0, 2].tolist() == [v & 255, (v >> 8) & 255, (v >> 16) & 255]


@pytest.mark.parametrize("width", [1, 3, 37, 1920])  # OpenCV's vector loop and its scalar tail
def test_depth_raw_rounds_half_to_even_like_rint(width):
    """The 24-bit level is round(depth / 1000 * (256**3 - 1)), halves to even, exactly as ``np.rint``
    gives: a level off by one is a silent error no round trip within a step would show."""
    rng = np.random.default_rng(width)
    levels = rng.integers(0, enc.DEPTH_LEVELS, (4, width)).astype(np.float64)
    ties = (levels + 0.5) / enc.DEPTH_LEVELS * enc.FAR_M  # at or next to a half level
    depth = np.concatenate([ties, rng.uniform(-5.0, 1200.0, (4, width)), np.full((1, width), enc.FAR_M)])
    expected = np.rint(np.clip(depth * (1.0 / enc.FAR_M), 0.0, 1.0) * enc.DEPTH_LEVELS).astype(np.int64)
    raw = enc.encode_depth_raw(depth).astype(np.int64)
    assert raw.shape == depth.shape + (3,)
    assert np.array_equal(raw[..., 0] | raw[..., 1] << 8 | raw[..., 2] << 16, expected)


@settings(max_examples=60, deadline=None)
@given(depths)
def test_depth_raw_round_trips_within_one_step(depth):
    decoded = enc.decode_depth_raw(enc.encode_depth_raw(depth))
    assert np.abs(decoded - depth.astype(np.float64)).max() <= enc.DEPTH_STEP_M


def test_depth_gray_and_log_follow_carla():
    depth = np.array([[0.0, 1000.0, 1000.0 / 300.0, 100.0, 2000.0]], dtype=np.float32)
    gray = enc.encode_depth_gray(depth)[..., 0]
    log = enc.encode_depth_log(depth)[..., 0]
    assert gray.tolist() == [[0, 255, round(255 / 300), round(25.5), 255]]
    expected_100 = round((1 + np.log(0.1) / 5.70378) * 255)
    assert log.tolist() == [[0, 255, 0, expected_100, 255]]


@settings(max_examples=40, deadline=None)
@given(depths)
def test_depth_images_are_gray_and_monotonic(depth):
    for name in ("depth_gray", "depth_log"):
        out = out_table.output(name).encode(depth)
        assert out.dtype == np.uint8 and out.shape == depth.shape + (3,)
        assert (out[..., 0] == out[..., 1]).all() and (out[..., 1] == out[..., 2]).all()
        order = np.argsort(depth.ravel(), kind="stable")
        assert (np.diff(out[..., 0].ravel()[order].astype(int)) >= 0).all()


@settings(max_examples=60, deadline=None)
@given(class_maps)
def test_semantic_encodings(classes):
    raw = enc.encode_semantic_raw(classes)
    assert (raw[..., 0] == classes).all() and not raw[..., 1:].any()
    assert (enc.encode_semantic_color(classes) == PALETTE[raw[..., 0]]).all()


@settings(max_examples=40, deadline=None)
@given(images)
def test_png_round_trip_and_determinism(image):
    data = enc.encode_png(image)
    assert data == enc.encode_png(image.copy())
    assert (enc.decode_png(data) == image).all()


def test_png_keeps_rgb_order():
    red = np.zeros((2, 3, 3), np.uint8)
    red[..., 0] = 255
    data = enc.encode_png(red)
    assert enc.decode_png(data)[0, 0].tolist() == [255, 0, 0]
    assert data[:8] == b"\x89PNG\r\n\x1a\n"


def test_encode_outputs_gives_every_output():
    h, w = 4, 5
    rgb = np.zeros((h, w, 3), np.uint8)
    depth = np.full((h, w), 1000.0, np.float32)
    classes = np.full((h, w), 20, np.uint8)
    out = out_table.encode_outputs({"rgb": rgb, "depth": depth, "classes": classes}, SEED_OUTPUTS)
    assert tuple(out) == SEED_OUTPUTS
    assert all(v.shape == (h, w, 3) and v.dtype == np.uint8 for v in out.values())
    with pytest.raises(ValueError, match="needs the 'instance' buffer"):
        out_table.encode_outputs({"rgb": rgb}, ("instance",))


@given(hnp.arrays(np.uint16, hnp.array_shapes(min_dims=2, max_dims=2, min_side=1, max_side=12)))
@settings(max_examples=25, deadline=None)
def test_png16_round_trips(ids):
    data = out_table.file_bytes("instance", out_table.output("instance").encode(ids))
    assert (out_table.read_output("instance", data) == ids).all()


@pytest.mark.parametrize(
    "name, array",
    [
        ("rgb", np.zeros((2, 2, 3), np.float32)),
        ("rgb", np.zeros((2, 2), np.uint8)),
        ("depth_raw", np.zeros((2, 2), np.uint8)),
        ("depth_log", np.full((2, 2), np.nan, np.float32)),
        ("semantic_raw", np.full((2, 2), NUM_CLASSES, np.uint8)),
        ("semantic_color", np.zeros((2, 2), np.int32)),
        ("instance", np.zeros((2, 2), np.uint8)),
        ("objects", np.zeros((2, 2), np.uint8)),
    ],
)
def test_bad_buffers_raise_naming_the_output(name, array):
    with pytest.raises(ValueError, match=name):
        out_table.output(name).encode(array)


def test_bad_png_input_raises():
    with pytest.raises(ValueError, match="semantic_color"):
        enc.encode_png(np.zeros((2, 2, 4), np.uint8), "semantic_color")
    with pytest.raises(ValueError, match="not a decodable PNG"):
        enc.decode_png(b"not a png")
    with pytest.raises(ValueError, match="disagree"):
        out_table.encode_outputs({"rgb": np.zeros((2, 2, 3), np.uint8), "depth": np.zeros((3, 2), np.float32)})


@pytest.mark.parametrize("shape, dtype", [((5, 7), np.uint8), ((5, 7), np.uint16), ((6, 3, 4), np.uint8),
                                          ((6, 3, 3), np.uint16), ((1, 1, 3), np.uint8)])
def test_png_bytes_round_trip_grey_rgba_and_16_bit(shape, dtype):
    import cv2

    image = np.random.default_rng(7).integers(0, np.iinfo(dtype).max + 1, shape).astype(dtype)
    data = enc.png_bytes(image)
    assert data == enc.png_bytes(image.copy())
    decoded = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)  # BGR(A) order
    if decoded.ndim == 3:
        decoded = decoded[..., [2, 1, 0, 3][: decoded.shape[2]]]
    assert decoded.dtype == image.dtype and (decoded == image).all()


def test_png_bytes_rejects_what_png_cannot_hold():
    for bad in (np.zeros((2, 2), np.float32), np.zeros((2, 2, 2), np.uint8), np.zeros((0, 3, 3), np.uint8)):
        with pytest.raises(ValueError, match="instance"):
            enc.png_bytes(bad, "instance")


def test_semantic_trainid_is_the_cityscapes_export_table():
    """The opt-in trainId output maps through the catalog's one table (the Cityscapes export's
    labelTrainIds too): road 0, sky 10, vehicle 13, unlabeled and excluded classes 255."""
    from exports.cityscapes import cityscapes_targets
    from domains.catalog import class_id

    names = ("road", "sky", "vehicle", "unlabeled", "road line", "pedestrian", "terrain")
    classes = np.array([[class_id(n) for n in names]], dtype=np.uint8)
    train = out_table.encode_outputs({"classes": classes}, ("semantic_trainid",))["semantic_trainid"]
    assert train.tolist() == [[0, 10, 13, 255, 255, 11, 9]]
    assert np.array_equal(train, cityscapes_targets(classes, None)["labelTrainIds"])
    data = out_table.file_bytes("semantic_trainid", train)
    assert data[25] == 0  # PNG colour type 0: one grey channel, as Cityscapes' *_labelTrainIds.png
    assert np.array_equal(out_table.read_output("semantic_trainid", data), train)
    with pytest.raises(ValueError):
        out_table.file_bytes("semantic_trainid", np.zeros((2, 2, 3), np.uint8))


def test_normals_round_trip_within_a_16_bit_step():
    rng = np.random.default_rng(0)
    n = rng.normal(size=(5, 7, 3))
    n /= np.linalg.norm(n, axis=-1, keepdims=True)
    n[0, 0] = 0.0  # no surface
    n = n.astype(np.float32)
    data = out_table.file_bytes("normals", out_table.encode_outputs({"normals": n}, ("normals",))["normals"])
    back = out_table.output("normals").decode(out_table.read_output("normals", data))
    assert back.dtype == np.float32 and np.abs(back - n).max() <= 1.0 / 65535 + 1e-6
    assert not back[0, 0].any() and np.allclose(np.linalg.norm(back[1:], axis=-1), 1.0, atol=1e-4)


def test_flow_uses_kittis_encoding():
    flow = np.array([[[1.5, -2.25, 1.0], [0.0, 0.0, 0.0], [-600.0, 0.015625, 1.0]]], np.float32)
    image = out_table.encode_outputs({"flow": flow}, ("flow",))["flow"]
    assert image.dtype == np.uint16
    assert image[0, 0].tolist() == [2**15 + 96, 2**15 - 144, 1] and image[0, 1].tolist() == [0, 0, 0]
    back = out_table.output("flow").decode(out_table.read_output("flow", out_table.file_bytes("flow", image)))
    assert back[0, 2].tolist() == [0.0, 0.0, 0.0]  # beyond KITTI's +-512 px: invalid, not clamped
    old = out_table.encode_outputs({"flow": flow}, ("flow",), old_rules=True)["flow"]  # roots made before rules
    assert old[0, 2].tolist() == [0, 2**15 + 1, 1] and np.array_equal(old[0, :2], image[0, :2])
    flow[0, 2] = 0.0
    assert np.allclose(back, flow)


def test_flow_beyond_the_encodings_range_is_invalid_at_full_hd_motion():
    """Issue 32: at 1920x1080 and 3 s between frames static pixels near the sides move 512-900 px;
    such a flow is stored invalid, while every motion the 16 bits hold keeps its value to 1/128 px."""
    rng = np.random.default_rng(0)
    flow = np.zeros((90, 160, 3), np.float32)
    flow[..., 0] = rng.uniform(-900, 900, (90, 160))
    flow[..., 1] = rng.uniform(-300, 300, (90, 160))
    flow[..., 2] = rng.random((90, 160)) < 0.9
    flow[::7, ::5, 0] = [[511.984375, -512.0] * 16] * 13  # the range's ends are held
    back = out_table.output("flow").decode(out_table.read_output("flow", out_table.file_bytes(
        "flow", out_table.encode_outputs({"flow": flow}, ("flow",))["flow"])))
    holdable = (flow[..., 2] > 0) & (flow[..., 0] >= -512) & (flow[..., 0] <= 511.984375)
    assert (back[..., 2] > 0).tolist() == holdable.tolist() and 0 < holdable.sum() < (flow[..., 2] > 0).sum()
    assert np.abs(back[holdable, :2] - flow[holdable, :2]).max() <= 1 / 128
    assert not back[~holdable].any()
