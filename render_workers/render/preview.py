"""Preview images: a contact sheet per weather (like the IDDA paper's Fig. 2) and an output strip.

``write_preview`` renders the first frame of episode 0 of each chosen scenario
(the same seeds a production run with ``seed`` uses) and writes:

* ``preview_<weather>.png``: rows = viewpoints, columns = towns, one sheet per
  weather present in the selection, labelled with cv2.putText;
* ``outputs_<scenario>.png``: the six outputs of the first scenario's frame
  side by side, each captioned with its output name.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np

from domains.catalog import active, scenario as lookup_scenario
from outputs.table import SEED_OUTPUTS, encode_outputs
from roots.episode_spec import EpisodeSpec
from roots.episode_spec import PAIRED, episode_seed
from outputs.encoding import encode_png
from render_workers.render.episode import DEFAULT_WORLD, render_episode
from render_workers.render.renderer import Renderer
from render_workers.worlds.scene import Frame

log = logging.getLogger(__name__)

MARGIN_PX = 36  # label band above columns and left of rows
CELL_WIDTH_MAX = 480  # thumbnails are scaled down to at most this width
BACKGROUND = (24, 24, 24)
INK = (235, 235, 235)


def _thumbnail(image: np.ndarray, width: int) -> np.ndarray:
    import cv2

    if image.shape[1] == width:
        return image
    height = max(1, round(image.shape[0] * width / image.shape[1]))
    return cv2.resize(image, (width, height), interpolation=cv2.INTER_AREA)


def _label(canvas: np.ndarray, text: str, x: int, y: int, scale: float = 0.6) -> None:
    import cv2

    cv2.putText(canvas, text, (x, y), cv2.FONT_HERSHEY_SIMPLEX, scale, INK, 1, cv2.LINE_AA)


def contact_sheet(cells: dict[tuple[str, str], np.ndarray], rows: list[str], cols: list[str],
                  title: str = "") -> np.ndarray:
    """A grid of equally sized RGB images keyed by (row, col); missing cells stay dark."""
    cell_h, cell_w = next(iter(cells.values())).shape[:2]
    top = MARGIN_PX * (2 if title else 1)
    canvas = np.full((top + len(rows) * cell_h, MARGIN_PX + len(cols) * cell_w, 3), BACKGROUND, np.uint8)
    if title:
        _label(canvas, title, 6, MARGIN_PX - 10, 0.7)
    for j, col in enumerate(cols):
        _label(canvas, col, MARGIN_PX + j * cell_w + 6, top - 10)
    for i, row in enumerate(rows):
        _label(canvas, row, 8, top + i * cell_h + cell_h // 2 + 6)
        for j, col in enumerate(cols):
            image = cells.get((row, col))
            if image is not None:
                y, x = top + i * cell_h, MARGIN_PX + j * cell_w
                canvas[y:y + cell_h, x:x + cell_w] = image
    return canvas


def output_strip(frame: Frame, width: int) -> np.ndarray:
    """The six outputs of a frame side by side, captioned."""
    outputs = encode_outputs(frame.buffers, SEED_OUTPUTS)
    panels = [_thumbnail(outputs[name], width) for name in SEED_OUTPUTS]
    h, w = panels[0].shape[:2]
    canvas = np.full((MARGIN_PX + h, len(panels) * w, 3), BACKGROUND, np.uint8)
    for k, (name, panel) in enumerate(zip(SEED_OUTPUTS, panels)):
        canvas[MARGIN_PX:, k * w:(k + 1) * w] = panel
        _label(canvas, name, k * w + 6, MARGIN_PX - 10)
    return canvas


def render_first_frame(code: str, width: int, height: int, seed: int, world: str,
                       renderer: Renderer | None = None) -> Frame:
    """Frame 0 of episode 0 of a scenario, seeded as a production run with ``seed`` would."""
    scen = lookup_scenario(code)
    spec = EpisodeSpec(scenario=scen.code, episode=0, seed=episode_seed(seed, scen, 0, PAIRED), frames=1,
                       width=width, height=height, split="train", run_seed=seed, outputs=SEED_OUTPUTS,
                       catalog=active().layer_json())  # a --catalog file's entries
    frames: list[Frame] = []
    render_episode(spec.drawing, frames.append, world=world, renderer=renderer)
    return frames[0]


def write_preview(out_dir, scenario_codes, width: int, height: int, seed: int,
                  world: str = DEFAULT_WORLD) -> list[Path]:
    """Render one frame per scenario; write contact sheets and an output strip. Returns paths."""
    codes = list(dict.fromkeys(scenario_codes))
    if not codes:
        raise ValueError("preview needs at least one scenario code")
    scenarios = [lookup_scenario(c) for c in codes]
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    cell_w = min(width, CELL_WIDTH_MAX)

    frames: dict[str, Frame] = {}
    for scen in scenarios:
        log.info("preview: rendering %s", scen.code)
        frames[scen.code] = render_first_frame(scen.code, width, height, seed, world)

    written: list[Path] = []
    for weather in active().weathers:  # catalog order, only weathers present in the selection
        chosen = [s for s in scenarios if s.weather == weather]
        if not chosen:
            continue
        rows = [v.code for v in active().viewpoints if any(s.viewpoint == v for s in chosen)]
        cols = [t.code for t in active().towns if any(s.town == t for s in chosen)]
        cells = {(s.viewpoint.code, s.town.code): _thumbnail(frames[s.code].buffers["rgb"], cell_w) for s in chosen}
        sheet = contact_sheet(cells, rows, cols, title=f"{weather.code} ({weather.name})")
        written.append(_write(out / f"preview_{weather.code}.png", sheet))

    first = scenarios[0].code
    written.append(_write(out / f"outputs_{first}.png", output_strip(frames[first], cell_w)))
    return written


def _write(path: Path, image: np.ndarray) -> Path:
    path.write_bytes(encode_png(image, path.name))
    return path
