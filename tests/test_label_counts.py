"""Label images counted by OpenCV's histogram (``outputs.objects.label_counts``) and post effects'
input made float by a table: the same numbers as numpy's, by a faster path."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from outputs.objects import label_counts


@settings(max_examples=60, deadline=None)
@given(st.sampled_from([np.uint8, np.uint16]), st.integers(1, 40), st.integers(1, 60), st.integers(0, 300),
       st.integers(0, 2**31 - 1))
def test_label_counts_are_numpys_bincount(dtype, h, w, minlength, seed):
    rng = np.random.default_rng(seed)
    top = int(np.iinfo(dtype).max) if seed % 3 == 0 else 30  # now and then the type's largest value
    labels = rng.integers(0, top, (h, w), dtype=dtype, endpoint=True)
    got = label_counts(labels, minlength)
    want = np.bincount(labels.ravel(), minlength=minlength)
    assert got.dtype == np.int64 and np.array_equal(got, want)
    assert np.array_equal(label_counts(labels[:, ::-1], minlength), want)  # a view with negative strides


def test_a_full_hd_frame_and_the_fallbacks():
    rng = np.random.default_rng(1)
    frame = rng.integers(0, 24, (1080, 1920), dtype=np.uint8)
    frame[:500] = 7  # one class over most of the frame: counts far beyond 2**16
    assert np.array_equal(label_counts(frame, 24), np.bincount(frame.ravel(), minlength=24))
    for odd in (np.zeros((0, 5), np.uint8), rng.integers(0, 9, (4, 5)), rng.integers(0, 9, 20).astype(np.uint8)):
        assert np.array_equal(label_counts(odd, 3), np.bincount(odd.ravel(), minlength=3))  # numpy's own path


@pytest.mark.parametrize("shape", [(1, 1, 3), (90, 160, 3), (1080, 1920, 3)])
def test_post_effects_take_rgb_over_255_as_numpy_computes_it(shape):
    import cv2

    from render_workers.render.postfx import _UNIT

    rgb = np.random.default_rng(2).integers(0, 256, shape, dtype=np.uint8)
    rgb.flat[:256] = np.arange(256)[: rgb.size]
    assert np.array_equal(cv2.LUT(rgb, _UNIT), np.multiply(rgb, np.float32(1.0 / 255.0), dtype=np.float32))
