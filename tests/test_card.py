"""The dataset card: its numbers match the manifest, its snippet decodes depth,
previews are linked (or rendered), and the command writes it."""

from __future__ import annotations

import json
import re
import shutil
import sys
import types

import numpy as np
import pytest
from PIL import Image
from typer.testing import CliRunner

from domains.catalog import LABELS
from manifests.reader import read_manifest
from tests.roots import part_of
from manifests.stats import share_table
from exports import card as card_mod
from outputs.encoding import decode_depth_raw
from tests.test_export import cli_app, make_tiny_root


@pytest.fixture
def root(tmp_path_factory, tmp_path):
    """A private copy of the tiny root: the card writes into it."""
    copy = tmp_path / "root"
    shutil.copytree(make_tiny_root(tmp_path_factory), copy)
    return copy


def table_rows(text: str, first_cell: str) -> list[list[str]]:
    """Cells of the markdown table whose header starts with ``first_cell``."""
    lines = text.splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(f"| {first_cell} |"))
    rows = []
    for line in lines[start + 2 :]:
        if not line.startswith("|"):
            break
        rows.append([c.strip().removeprefix("**").removesuffix("**") for c in line.strip("|").split("|")])
    return rows


def test_card_numbers_match_the_manifest(root):
    result = card_mod.write_card(card_mod.CardConfig(root=str(root)))
    text = (root / "README.md").read_text()
    table = read_manifest(str(root))
    assert result.frames == len(table) and result.card == str(root / "README.md")
    assert text.startswith("---\n") and "\n---\n\n# IDDA-style synthetic driving dataset" in text
    assert f"{len(table):,} frames in 5 episodes over 5 scenarios" in text and "at 64x36" in text

    rows = table_rows(text, "scenario")
    manifest_rows = table.to_pylist()
    for cells in rows[:-1]:
        code, train, val, test, total = cells[0], *map(int, cells[4:])
        mine = [r for r in manifest_rows if r["scenario"] == code]
        assert (train, val, test, total) == tuple(sum(r["split"] == s for r in mine) for s in ("train", "val", "test")) + (len(mine),)
    assert [c[0] for c in rows[:-1]] == sorted({r["scenario"] for r in manifest_rows})
    assert int(rows[-1][-1].replace(",", "")) == len(table)

    shares = {r["class"]: r for r in share_table(table).to_pylist()}
    class_rows = table_rows(text, "id")
    assert len(class_rows) == len(LABELS)
    # shares are printed to 3 decimals: within half a unit of the last digit, a tie (0.3125 -> 0.312) included
    for cells in class_rows:
        name = cells[1].removesuffix("\\*")
        assert float(cells[5]) == pytest.approx(100 * shares[name]["share"], abs=5.001e-4)
        assert float(cells[6]) == pytest.approx(100 * shares[name]["paper_share"], abs=5.001e-4)
        assert cells[1].endswith("\\*") == (not LABELS[int(cells[0])].evaluated)

    assert Image.open(root / "class_shares.png").format == "PNG"
    run = json.loads((root / "run.json").read_text())
    assert run["git_revision"] in text and json.dumps(run["config"], indent=2, sort_keys=True) in text
    assert "No preview in this root yet" in text
    # Five one-episode scenarios of three scenes: the planner's rule gives every split, the weathers of a
    # scene share its split (docs/layout.md, "Splits"): T01 A train, T01 J val, T07 A test.
    assert [int(c.replace(",", "")) for c in rows[-1][4:7]] == [4, 4, 2]  # train/val/test frames (2 per episode)
    assert "Any run of three or more episodes has all three splits" in text
    # What the root holds, by name: this root has all eight outputs, not "six images".
    assert "each with 8 output file(s): rgb, depth_raw, depth_gray, depth_log, semantic_raw, " \
           "semantic_color, instance, objects" in text and "six images" not in text


def test_card_header_parses_with_huggingface_hub(root):
    from huggingface_hub import DatasetCard

    card_mod.write_card(card_mod.CardConfig(root=str(root)))
    card = DatasetCard.load(root / "README.md")
    data = card.data.to_dict()
    assert data["license"] == "cc-by-4.0" and "image-segmentation" in data["task_categories"]
    table = read_manifest(str(root))
    (config,) = data["configs"]
    assert config["config_name"] == "manifest"
    files = {f["split"]: f["path"] for f in config["data_files"]}
    assert list(files) == ["train", "validation", "test"]  # HF's split names
    want = {"train": "train", "validation": "val", "test": "test"}
    for split, paths in files.items():  # each split lists exactly its episodes' parts
        rows = [r for r in table.to_pylist() if r["split"] == want[split]]
        assert paths == sorted(part_of(root, r["scenario"], r["episode"]) for r in rows if r["frame"] == 0)
        assert all(root.joinpath(p).is_file() for p in paths)
    sizes = {s["name"]: s for s in data["dataset_info"]["splits"]}
    assert list(sizes) == list(files)
    assert sum(s["num_examples"] for s in sizes.values()) == len(table)
    assert all(s["num_bytes"] > 0 for s in sizes.values())
    assert card.text.lstrip().startswith("# IDDA-style synthetic driving dataset")
    bibtex = re.search(r"```bibtex\n(.*?)```", card.text, re.S).group(1)
    assert bibtex.startswith("@article{alberti2020idda,") and "Robotics and Automation Letters" in bibtex
    assert "Alberti, Emanuele and Tavera, Antonio and Masone, Carlo and Caputo, Barbara" in bibtex


def test_card_depth_snippet_decodes_depth(root, monkeypatch):
    card_mod.write_card(card_mod.CardConfig(root=str(root)))
    text = (root / "README.md").read_text()
    snippet = next(b for b in re.findall(r"```python\n(.*?)```", text, re.S) if "depth_m" in b)
    assert len(snippet.strip().splitlines()) == 3
    monkeypatch.chdir(root)
    scope: dict = {}
    exec(snippet, scope)
    path = re.search(r'imread\("([^"]+)"', snippet).group(1)
    expected = decode_depth_raw(np.array(Image.open(root / path).convert("RGB")))
    assert np.allclose(scope["depth_m"], expected)


def test_card_links_and_renders_previews(root, monkeypatch):
    (root / "preview").mkdir()
    Image.new("RGB", (8, 8)).save(root / "preview" / "strip.png")
    Image.new("RGB", (8, 8)).save(root / "preview" / "contact_sheet_CN.png")
    result = card_mod.write_card(card_mod.CardConfig(root=str(root)))
    assert result.previews == ["preview/contact_sheet_CN.png", "preview/strip.png"]
    assert "![contact_sheet_CN.png](preview/contact_sheet_CN.png)" in (root / "README.md").read_text()

    calls = []

    def write_preview(out_dir, codes, width, height, seed, world="procedural"):
        calls.append((list(codes), width, height, seed, world))
        path = f"{out_dir}/contact_sheet_HRN.png"
        Image.new("RGB", (width, height)).save(path)
        return [path]

    monkeypatch.setitem(sys.modules, "render_workers.render.preview", types.SimpleNamespace(write_preview=write_preview))
    result = CliRunner().invoke(cli_app(), ["card", str(root), "--contact-sheet"])
    assert result.exit_code == 0, result.output
    codes = sorted({r["scenario"] for r in read_manifest(str(root)).to_pylist()})
    assert calls == [(codes, 64, 36, 3, "test")]
    assert "linked preview preview/contact_sheet_HRN.png" in result.output
    assert "(preview/contact_sheet_HRN.png)" in (root / "README.md").read_text()


def test_card_of_a_damaged_root_says_it_failed_verification(root):
    """Issue 33: ``idda card`` on a damaged root exited 0 with no warning. It verifies
    first: the card says the root failed, and the command warns and exits 1."""
    result = CliRunner().invoke(cli_app(), ["card", str(root)])
    assert result.exit_code == 0, result.output
    assert "Verified when this card was written: all" in (root / "README.md").read_text()
    victim = next(root.glob("T01_*/**/rgb/*.png"))
    victim.write_bytes(victim.read_bytes()[:-4] + b"bad!")
    result = CliRunner().invoke(cli_app(), ["card", str(root)])
    assert result.exit_code == 1
    assert f"warning: {root} failed verification (1 corrupt), and the card says so" in result.output
    text = (root / "README.md").read_text()
    assert "**This root failed verification when this card was written** (1 corrupt)" in text
    result = CliRunner().invoke(cli_app(), ["card", str(root), "--no-verify"])
    assert result.exit_code == 0 and "Not verified when this card was written" in (root / "README.md").read_text()


def test_card_command_errors(tmp_path):
    result = CliRunner().invoke(cli_app(), ["card", str(tmp_path)])
    assert result.exit_code == 2
    assert result.output.strip() == (f"error: {tmp_path} is not an output root (no idda-root.json, run.json or "
                                     f"manifest/ there); `idda produce --out {tmp_path}` makes one")


def test_documented_output_table_is_the_output_table():
    from pathlib import Path

    from outputs.table import markdown_table

    layout = (Path(__file__).resolve().parents[1] / "docs" / "layout.md").read_text()
    assert "\n".join(markdown_table()) in layout
