"""reports.weathers (docs/weathers.md's pictures) on a tiny run: the sheet holds one labelled row
per weather, the strip one tile per frame of the shift, and the bytes repeat."""

from __future__ import annotations

import cv2
import numpy as np

from reports import weathers


def test_pictures_are_laid_out_and_deterministic(tmp_path):
    small = {"width": 64, "height": 36, "world": "test"}
    sheet, strip = weathers.write_pictures(str(tmp_path / "a"), **small)
    again = weathers.write_pictures(str(tmp_path / "b"), **small)
    assert [open(p, "rb").read() for p in (sheet, strip)] == [open(p, "rb").read() for p in again]
    sheet_img = cv2.imread(sheet)
    strip_img = cv2.imread(strip)
    assert sheet_img.shape == (36 * len(weathers.SHEET_WEATHERS), 64 * len(weathers.SHEET_FRAMES), 3)
    assert strip_img.shape == (36, 64 * weathers.STRIP_FRAMES, 3)
    # the night row is darker than the noon row; the shift's last tile darker than its first
    rows = sheet_img.reshape(len(weathers.SHEET_WEATHERS), 36, -1, 3).mean(axis=(1, 2, 3))
    by_weather = dict(zip(weathers.SHEET_WEATHERS, rows))
    assert by_weather["NT"] < 0.7 * by_weather["CN"]  # labels cover much of a 64x36 tile
    tiles = strip_img.reshape(36, weathers.STRIP_FRAMES, 64, 3).mean(axis=(0, 2, 3))
    # darker frame by frame while the sun sets; frames 4 and 5 (sun -16 and -25 deg) are both full night, lit
    # only by the lamps, windows and cars in view
    assert tiles[-1] < 0.7 * tiles[0] and np.all(np.diff(tiles[1:5]) < 0) and abs(tiles[5] - tiles[4]) < 2
