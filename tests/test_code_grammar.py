"""Issue 32: one grammar for scenario codes, the catalog's. A domain file may declare any code of
letters and digits (a town not like T01, lower-case and long weathers, two-letter and digit
viewpoints); every parser of paths and part names takes its pattern from the catalog, so frames,
parts and indexes of such codes are seen by status, query, verify, repair, export and resume."""

from __future__ import annotations

import pytest

from manifests.catalog import SCENARIO_RE, format_code, split_code
from manifests.domainfile import CODE_PATTERN
from manifests.layout import LAYOUTS, frame_path, match_frame_file
from manifests.reader import _INDEX_RE
from manifests.schema import PART_RE, index_path, part_path

# one code of every legal shape per axis: the paper's, digits, lower case, long and mixed case
TOWNS = ("T01", "Oslo", "t7", "42", "TownWithALongName9")
WEATHERS = ("CN", "CNtoNT", "FG1", "mist", "x")
VIEWPOINTS = ("A", "B2", "7", "bus", "TR")
SHAPES = [format_code(t, w, v) for t, w, v in zip(TOWNS, WEATHERS, VIEWPOINTS)] + [
    format_code(t, w, v) for t, w, v in zip(TOWNS, reversed(WEATHERS), VIEWPOINTS[1:] + VIEWPOINTS[:1])]


@pytest.mark.parametrize("code", SHAPES)
def test_every_parser_reads_every_legal_code(code):
    town, weather, view = split_code(code)
    assert all(CODE_PATTERN.fullmatch(part) for part in (town, weather, view))  # a domain file accepts each part
    for rows in (None, 72):
        match = PART_RE.match(part_path(code, 12, rows))
        assert match is not None, part_path(code, 12, rows)
        assert (match["scenario"], match["town"], match["weather"], match["viewpoint"], int(match["episode"])) == (
            code, town, weather, view, 12)
    assert _INDEX_RE.match(index_path(code))["scenario"] == code
    for layout in LAYOUTS:
        for output, fmt in (("rgb", "png"), ("rgb", "jpg"), ("instance", "png"), ("objects", "png")):
            rel = frame_path(code, output, "0012_003", fmt, layout)
            match = match_frame_file(rel, (layout,))
            assert match is not None, rel
            assert (match["scenario"], match["output"], int(match["episode"]), int(match["frame"])) == (
                code, output, 12, 3)


@pytest.mark.parametrize("bad", ["T01_CN", "T01_CN_A_B", "T01__A", "T01_C-N_A", "T01_CN_*", "T01_CN_A ", "T01_CÑ_A"])
def test_what_the_grammar_refuses(bad):
    assert SCENARIO_RE.fullmatch(bad) is None
    with pytest.raises(ValueError, match="malformed scenario code"):
        split_code(bad)


def test_names_that_are_not_ours_stay_unmatched():
    code = "Oslo_mist_B2"
    assert PART_RE.match(f"manifest/town=Oslo/weather=mist/viewpoint=B2/Oslo_mist_B3_e0000.parquet") is None
    assert PART_RE.match(f"manifest/town=Oslo/weather=mist/viewpoint=B2/{code}_e0000_n0.parquet") is None
    assert match_frame_file(f"{code}/e0000/rgb/0000_000_Oslo_mist_B3.png") is None  # another scenario's name
    assert match_frame_file(f"{code}/e0000/rgb/0001_000_{code}.png") is None  # another episode's name
    assert match_frame_file(f"{code}/e0000/rgb/0000_000_{code}.exr") is None  # not the output's format
