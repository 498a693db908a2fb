"""The pictures of docs/weathers.md: the weathers beyond the paper, and a shift inside an episode.

* A contact sheet: one paired episode (the same scene, roots.episode_spec PAIRED) of
  ``TOWN``/``VIEWPOINT`` under each weather of ``SHEET_WEATHERS``, one column per
  frame picked, one row per weather, each labelled.
* A strip: the frames of one shifting episode (``SHIFT``, e.g. CNtoNT) side by
  side, each labelled with its sun altitude from its condition columns.

Rendered in this process with the episode renderer (no root, no cluster), encoded
with OpenCV: the same inputs give the same bytes. Run ``python -m reports.weathers``
(procedural T01 at 320x180, about a minute on two cores).
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from domains.catalog import format_code, scenario
from render_workers.render import episode
from render_workers.render.renderer import Renderer
from roots.episode_spec import PAIRED, EpisodeSpec, episode_seed

TOWN, VIEWPOINT = "T01", "A"
SHEET_WEATHERS = ("CN", "FG", "NT", "SN")
SHEET_FRAMES = (0, 2)  # frames of the episode shown per weather
SHIFT = "CNtoNT"
STRIP_FRAMES = 6
WIDTH, HEIGHT = 320, 180
SEED = 0
WORLD = "procedural"
INTERVAL_S = 3.0

log = logging.getLogger(__name__)


def episode_frames(weather: str, frames: int, *, width: int = WIDTH, height: int = HEIGHT, world: str = WORLD,
                   interval_s: float = INTERVAL_S, renderer=None) -> list:
    """The rendered frames (``render_workers.worlds.scene.Frame``) of episode 0 of TOWN_weather_VIEWPOINT,
    seeded as a new (paired) root seeds it."""
    code = format_code(TOWN, weather, VIEWPOINT)
    spec = EpisodeSpec(code, 0, episode_seed(SEED, scenario(code), 0, PAIRED), frames, width, height, "train",
                       SEED, frame_interval_s=interval_s)
    got: list = []
    episode.render_episode(spec.drawing, got.append, world=world, renderer=renderer)
    return got


def _label(image: np.ndarray, text: str) -> np.ndarray:
    """``image`` (RGB uint8) with ``text`` in its top-left corner on a dark band."""
    import cv2

    out = image.copy()
    scale = max(0.35, image.shape[1] / 800)
    (w, h), base = cv2.getTextSize(text, cv2.FONT_HERSHEY_SIMPLEX, scale, 1)
    cv2.rectangle(out, (0, 0), (w + 8, h + base + 6), (0, 0, 0), -1)
    cv2.putText(out, text, (4, h + 3), cv2.FONT_HERSHEY_SIMPLEX, scale, (255, 255, 255), 1, cv2.LINE_AA)
    return out


def sheet_image(rows: dict[str, list]) -> np.ndarray:
    """weather -> frames: one row per weather, the SHEET_FRAMES of each, labelled."""
    lines = []
    for weather, frames in rows.items():
        picked = [f for f in frames if f.index in SHEET_FRAMES]
        lines.append(np.concatenate([_label(f.buffers["rgb"], f"{weather}  frame {f.index}") for f in picked], 1))
    return np.concatenate(lines, 0)


def strip_image(frames: list) -> np.ndarray:
    """A shifting episode's frames side by side, each labelled with its sun altitude."""
    return np.concatenate([_label(f.buffers["rgb"], f"{f.conditions['sun_altitude_deg']:.0f} deg")
                           for f in frames], 1)


def png(image: np.ndarray) -> bytes:
    import cv2

    ok, data = cv2.imencode(".png", cv2.cvtColor(image, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_PNG_COMPRESSION, 9])
    if not ok:
        raise ValueError("could not encode the picture as PNG")
    return data.tobytes()


def write_pictures(out_dir: str, **render) -> tuple[str, str]:
    """Render and write weathers_sheet.png and weathers_shift.png into ``out_dir``; returns their paths."""
    frames = max(SHEET_FRAMES) + 1
    with Renderer() as renderer:
        rows = {w: episode_frames(w, frames, renderer=renderer, **render) for w in SHEET_WEATHERS}
        strip = episode_frames(SHIFT, STRIP_FRAMES, renderer=renderer, **render)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    sheet_path, strip_path = out / "weathers_sheet.png", out / "weathers_shift.png"
    sheet_path.write_bytes(png(sheet_image(rows)))
    strip_path.write_bytes(png(strip_image(strip)))
    return str(sheet_path), str(strip_path)


def main(out_dir: str = "docs/images") -> None:
    for path in write_pictures(out_dir):
        log.info("wrote %s", path)


if __name__ == "__main__":
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    main()
