"""--rgb-format jpg: the rgb output as a JPEG (quality 95), recorded with its encoder,
never mixed with PNG in one root, and read by every reader."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest
from typer.testing import CliRunner

from outputs import encoding as enc
from outputs.table import extension, file_bytes, markdown_table, read_output
from manifests.reader import read_manifest
from manifests.layout import EPISODE_DIRS, FLAT, frame_path
from roots.verify import verify
from storage import Storage
from tests.roots import render_root

DOMAINS = "T01_CN_A"
runner = CliRunner()


def cli_app():
    from pipeline.cli import data as cli_data
    from pipeline.cli import app

    cli_data.register(app)
    return app


def run_config(rgb_format: str, frames: int = 2):
    from pipeline.settings import PlanConfig, RunConfig

    return RunConfig(plan=PlanConfig(domains=DOMAINS, frames_per_scenario=frames, width=64, height=36, seed=4,
                                     rgb_format=rgb_format), world="test")


@pytest.fixture(scope="module")
def jpeg_root(tmp_path_factory):
    root = tmp_path_factory.mktemp("jpeg") / "root"
    render_root(root, run_config("jpg"))
    return root


def test_jpeg_bytes_are_a_quality_95_jpeg_and_deterministic():
    rng = np.random.default_rng(1)
    image = cv2.GaussianBlur(rng.integers(0, 256, (72, 128, 3), dtype=np.uint8), (9, 9), 3)
    data = enc.encode_jpeg(image)
    assert data[:3] == b"\xff\xd8\xff" and data == enc.encode_jpeg(image.copy())
    back = enc.decode_jpeg(data)
    assert back.shape == image.shape and np.abs(back.astype(int) - image).mean() < 3.0  # lossy, but close
    assert file_bytes("rgb", image, "jpg") == data and read_output("rgb", data, "x/0000_000_T01_CN_A.jpg").shape == image.shape
    assert file_bytes("rgb", image) == enc.encode_png(image, "rgb")  # png stays the default
    with pytest.raises(ValueError, match="HxWx3"):
        enc.encode_jpeg(image[..., 0])
    with pytest.raises(ValueError, match="valid formats: png, jpg"):
        extension("rgb", "webp")


def test_only_the_rgb_output_changes_format():
    assert extension("rgb", "jpg") == "jpg" and extension("rgb") == "png"
    assert extension("semantic_raw", "jpg") == "png" and extension("objects", "jpg") == "parquet"
    assert frame_path("T01_CN_A", "rgb", "0000_001", "jpg", EPISODE_DIRS) == "T01_CN_A/e0000/rgb/0000_001_T01_CN_A.jpg"
    assert frame_path("T01_CN_A", "rgb", "0000_001", "jpg", FLAT) == "T01_CN_A/rgb/0000_001_T01_CN_A.jpg"
    assert "| `rgb` | jpg |" in "\n".join(markdown_table(rgb_format="jpg"))
    assert "--rgb-format jpg" in "\n".join(markdown_table())


def test_encoder_identity_names_the_jpeg_encoder():
    assert enc.encoder_identity() == enc.encoder_identity("png") and "jpeg" not in enc.encoder_identity()
    jpg = enc.encoder_identity("jpg")
    assert jpg.startswith(enc.encoder_identity()) and f"quality {enc.JPEG_QUALITY}" in jpg and cv2.__version__ in jpg


def test_a_jpeg_root_holds_jpeg_rgb_files_and_verifies(jpeg_root):
    table = read_manifest(str(jpeg_root))
    rgb = table.column("rgb_path").to_pylist()
    assert len(rgb) == 2 and all(p.endswith(".jpg") and (jpeg_root / p).read_bytes()[:2] == b"\xff\xd8" for p in rgb)
    assert all(p.endswith(".png") for p in table.column("semantic_raw_path").to_pylist())
    record = json.loads((jpeg_root / "run.json").read_text())
    assert record["config"]["rgb_format"] == "jpg" and record["encoder"] == enc.encoder_identity("jpg")
    report = verify(str(jpeg_root))
    assert report.ok, report.problems


def test_the_same_spec_gives_the_same_jpeg_bytes(jpeg_root, tmp_path):
    again = tmp_path / "again"
    render_root(again, run_config("jpg"))
    for rel in read_manifest(str(jpeg_root)).column("rgb_path").to_pylist():
        assert (again / rel).read_bytes() == (jpeg_root / rel).read_bytes()


def test_resume_or_extend_never_mixes_rgb_formats(jpeg_root, tmp_path):
    from pipeline.provenance import RunConfigError, prepare_root

    storage = Storage.from_uri(str(jpeg_root))
    for fmt, extend in (("png", False), ("png", True)):
        with pytest.raises(RunConfigError, match="another encoder"):
            prepare_root(storage, run_config(fmt, frames=3), extend=extend)
    prepare_root(storage, run_config("jpg"))  # the same format resumes
    from pipeline.provenance import check_rows

    with pytest.raises(RunConfigError, match="holds jpg rgb files, this run asks for png"):
        check_rows(storage, run_config("png"))  # the rows say so too, whatever run.json says
    png_root = tmp_path / "png"
    render_root(png_root, run_config("png"))
    with pytest.raises(RunConfigError, match="another encoder"):
        prepare_root(Storage.from_uri(str(png_root)), run_config("jpg", frames=3), extend=True)


def test_loaders_read_the_jpeg(jpeg_root):
    from manifests.query import Query
    from analysis.loaders import FrameDataset

    data = FrameDataset(str(jpeg_root), Query(), outputs=("rgb", "semantic_raw"))
    sample = data[0]
    assert sample["rgb"].shape == (36, 64, 3) and sample["rgb"].dtype == np.uint8
    assert sample["semantic"].shape == (36, 64)


def test_exports_of_a_jpeg_root(jpeg_root, tmp_path):
    from exports import export as ex

    cs = tmp_path / "cs"
    ex.export(ex.ExportConfig(root=str(jpeg_root), to=str(cs), format="cityscapes", files="copy"))
    images = sorted(cs.glob("leftImg8bit/*/*/*_leftImg8bit.png"))
    assert len(images) == 2
    table = read_manifest(str(jpeg_root))
    by_frame = {f"{s.replace('_', '-')}_{e:06d}_{f:06d}": p for s, e, f, p in zip(
        *(table.column(c).to_pylist() for c in ("scenario", "episode", "frame", "rgb_path")))}
    for image in images:  # a real PNG holding exactly the JPEG's pixels
        assert image.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
        source = by_frame[image.name.removesuffix("_leftImg8bit.png")]
        assert (enc.decode_png(image.read_bytes()) == enc.decode_jpeg((jpeg_root / source).read_bytes())).all()
    idda = tmp_path / "idda"
    ex.export(ex.ExportConfig(root=str(jpeg_root), to=str(idda), format="idda", files="copy"))
    jpgs = sorted(idda.glob("*/RGB/*.jpg"))
    assert len(jpgs) == 2  # the root's own JPEGs, not re-encoded
    assert {p.read_bytes() for p in jpgs} == {(jpeg_root / p).read_bytes() for p in by_frame.values()}


def test_cli_produce_rgb_format_and_card(tmp_path):
    root = tmp_path / "root"
    args = ["produce", "--domains", DOMAINS, "--frames-per-scenario", "1", "--width", "64", "--height", "36",
            "--world", "test", "--workers", "1", "--out", str(root)]
    bad = runner.invoke(cli_app(), args + ["--rgb-format", "webp"])
    assert bad.exit_code == 2 and "valid formats: png, jpg" in bad.output
    result = runner.invoke(cli_app(), args + ["--rgb-format", "jpg"])
    assert result.exit_code == 0, result.output
    assert list((root / DOMAINS / "e0000" / "rgb").glob("*.jpg"))
    again = runner.invoke(cli_app(), args)  # png into a jpg root: one line, exit 2
    assert again.exit_code == 2 and "another encoder" in again.output and len(again.output.strip().splitlines()) == 1
    card = runner.invoke(cli_app(), ["card", str(root)])
    assert card.exit_code == 0, card.output
    assert "| `rgb` | jpg |" in (root / "README.md").read_text()
