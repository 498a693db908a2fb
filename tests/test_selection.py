import pytest

from domains.selection import parse_selection


def codes(text):
    return [s.code for s in parse_selection(text)]


def test_all_and_empty():
    assert len(codes("all")) == 105
    with pytest.raises(ValueError, match="empty selection"):  # never "everything" (issue 21.6)
        codes("")


def test_code_list_and_wildcards():
    assert codes("T01_CS_A,T01_CS_J") == ["T01_CS_A", "T01_CS_J"]
    assert codes("T07_HRN_*") == [f"T07_HRN_{v}" for v in "AMJVB"]
    assert len(codes("T01_*_*")) == 15
    assert codes("t01_cs_a") == ["T01_CS_A"]


def test_axis_filters_and_ranges():
    best = codes("towns=T01-T06 weathers=CN viewpoints=A,M")
    assert len(best) == 12 and all("_CN_" in c for c in best)
    assert codes("town=T07;weather=HRN;viewpoint=J,B") == ["T07_HRN_J", "T07_HRN_B"]


def test_codes_intersect_with_filters():
    assert codes("T01_*_* viewpoints=A") == ["T01_CN_A", "T01_CS_A", "T01_HRN_A"]


def test_catalog_order_and_no_duplicates():
    assert codes("T02_CN_A T01_CN_A T01_CN_A") == ["T01_CN_A", "T02_CN_A"]


@pytest.mark.parametrize(
    "text, message",
    [
        ("towns=T09", "unknown town 'T09'; valid towns: T01, T02, T03, T04, T05, T06, T07"),
        ("weathers=SNOW", "valid weathers: CN, CS, HRN"),
        ("viewpoints=Q", "valid viewpoints: A, M, J, V, B"),
        ("cities=T01", "unknown selection axis"),
        ("T01_CS", "malformed scenario code"),
        ("T01_CS_A_X", "malformed scenario code"),
        ("towns=T05-T02", "empty town range"),
        ("towns=", "empty value list"),
        ("towns=T01 towns=T02", "given twice"),
        ("T01_CN_A viewpoints=B", "matches no scenario"),
    ],
)
def test_errors(text, message):
    with pytest.raises(ValueError, match=message.replace("(", r"\(")):
        parse_selection(text)
