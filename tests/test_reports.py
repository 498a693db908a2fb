"""make report's generators (reports/) run on the committed figures: the page is what they write, and the
charts draw. The rendering half (make report itself) is too slow for the suite; this covers the rest."""

from __future__ import annotations

import json
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_worlds_page_is_what_the_generator_writes_from_its_json():
    from reports.worlds_md import markdown

    result = json.loads((ROOT / "docs" / "worlds.json").read_text())
    assert markdown(result) == (ROOT / "docs" / "worlds.md").read_text()


def test_report_charts_draw_from_the_committed_stats():
    from reports.charts import presence_png, town_share_png
    from reports.sample import span, urban_towns

    stats = json.loads((ROOT / "docs" / "worlds.json").read_text())["stats"]
    for png in (presence_png(stats), town_share_png(stats)):
        assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 5_000
    assert span(urban_towns()) == "T01-T06"
