"""CLI commands for the people who train on a dataset: export, evaluate, distances, card, shifts, view.

``register(app)`` adds them to the ``idda`` typer app (``pipeline.cli`` calls
it at its bottom); it is idempotent. Like every command, each one parses its
options, builds one config and calls one library function; expected errors
become one line and exit code 2 via ``pipeline.cli.common.user_errors``.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path
from typing import Annotated, Optional

import typer

from analysis.distances import DistanceConfig, domain_distances, embedding_png, format_distance_table, parse_pairs
from analysis.evaluate import EvaluateConfig, evaluate as run_evaluate, format_report
from analysis.viewer import ViewConfig, view as run_view
from analysis.view_picture import picture_png, read_recording
from domains.catalog import using
from exports.card import CardConfig, write_card
from exports.export import ExportConfig, export as run_export
from exports.webdataset import SHARD_SIZE, parse_size
from outputs.table import parse_outputs
from pipeline.cli.common import (
    DOMAINS_HELP, ROOT_DOMAINS_HELP, ROOT_HELP, Domains, HasClass, MinShare, PerScenario, Preset, SampleSeed, Splits, Total,
    build_query, count, of_held, of_held_sensors, output_root, user_errors, write_local,
)
from pipeline.cli.domain_files import CatalogFile, root_catalog
from pipeline.settings import CONFIG_SHAPE

Real = Annotated[Optional[Path], typer.Option(
    "--real", help="A real dataset folder in Cityscapes layout (leftImg8bit/, gtFine/ labelIds for shifts): "
    "the domain 'real' in --pairs; for distances also CamVid's layout (train/, val/...).")]
RealSplits = Annotated[list[str], typer.Option("--real-split", help="Split of the --real folder to read; repeatable.")]


def export(
    root: str = typer.Argument(..., help=ROOT_HELP),
    fmt: str = typer.Option(..., "--format", "-f", help="Layout: cityscapes, idda, hf (HuggingFace Parquet shards), coco (instances as RLE masks and boxes; needs the instance and objects outputs) or webdataset (tar shards)."),
    to: str = typer.Option(..., "--to", help="Target directory (local; s3:// too for webdataset); must be empty or absent unless --force (webdataset: or an unfinished export of the same selection, which resumes)."),
    preset: Preset = None,
    domains: Domains = None,
    split: Splits = [],
    has_class: HasClass = [],
    min_share: MinShare = [],
    per_scenario: PerScenario = None,
    total: Total = None,
    seed: SampleSeed = None,
    copy: bool = typer.Option(False, "--copy", help="Copy files instead of hard-linking them."),
    symlink: bool = typer.Option(False, "--symlink", help="Symlink files instead of hard-linking them."),
    force: bool = typer.Option(False, "--force", help="Replace a non-empty target directory."),
    skip_damaged: bool = typer.Option(False, "--skip-damaged", help="Leave out frames whose files do not match the manifest's checksums (counted) instead of refusing."),
    threads: int = typer.Option(8, help="Frames converted in parallel."),
    as_split: Optional[str] = typer.Option(None, "--as-split", help="Put every exported frame in this split (train, val or test)."),
    splits: str = typer.Option("scenario", "--splits", help="idda split files: scenario (train/val/test.json) or feddrive (FedDrive's federated splits)."),
    holdout: Optional[str] = typer.Option(None, help="With --splits feddrive: domains whose frames form test_user_diff_domain, e.g. 'towns=T07'."),
    outputs: Optional[str] = typer.Option(None, "--outputs", help="webdataset: the outputs each sample holds, comma-separated (default: every output the frames hold)."),
    shard_size: str = typer.Option("1GB", "--shard-size", help="webdataset: the most bytes a shard holds, e.g. 1GB, 256MB."),
    catalog: CatalogFile = None,
    sensor: Optional[str] = typer.Option(None, "--sensor", help="In a root made with a rig of several sensors: the one sensor whose frames to export (docs/conventions.md, 'Sensor rigs')."),
) -> None:
    """Export a query's frames as a Cityscapes, IDDA, HuggingFace, COCO or WebDataset layout (never re-renders).

    cityscapes: leftImg8bit/ and gtFine/ (labelIds, labelTrainIds, RGBA color,
    instanceIds) that cityscapesScripts and torchvision read. idda:
    <scenario>/RGB/*.jpg, <scenario>/Semantic/*.png (class ids) and split
    files. hf: Parquet shards with embedded images and a card. webdataset:
    <split>/<split>-NNNNNN.tar shards (one sample per frame: its files and
    manifest row as JSON), resumable. Splits are the manifest's, by episode
    (--as-split puts every frame in one split).
    """
    with user_errors(), using(root_catalog(root, catalog)):
        if copy and symlink:
            raise ValueError("give at most one of --copy and --symlink")
        output_root(root)
        query = build_query(preset, domains, split, has_class, min_share, per_scenario, total, seed)
        if sensor is not None:
            query = replace(query, sensors=(sensor,))
            query.validate()
        config = ExportConfig(
            root=root, to=str(to), format=fmt, query=query,
            files="copy" if copy else "symlink" if symlink else "hardlink", force=force, threads=threads,
            as_split=as_split, splits=splits, holdout=holdout, skip_damaged=skip_damaged,
            outputs=parse_outputs(outputs) if outputs is not None else None,
            shard_size=parse_size(shard_size) if fmt == "webdataset" else SHARD_SIZE,
        )
        report = run_export(config)
        if report.damaged:
            typer.echo(f"warning: left out {count(report.skipped, 'frame')} with {count(len(report.damaged), 'damaged file')} "
                       f"(first: {report.damaged[0]}); `idda verify` lists the damage", err=True)
        for code, missing in sorted(report.shortfall.items()):
            typer.echo(f"warning: {code} has {missing} frame(s) fewer than asked for", err=True)
        splits = ", ".join(f"{n:,} {s}" for s, n in report.per_split.items() if n)
        if report.resumed:
            typer.echo(f"kept {count(report.resumed, 'shard')} an earlier run had written (verified)")
        typer.echo(
            f"exported {of_held_sensors(report.frames, report.held, report.sensor_frames, report.held_sensor_frames)} "
            f"({splits}) as {report.format} to {report.target}: "
            f"{report.files:,} files in {report.seconds:.1f} s"
        )


def evaluate(
    export: Path = typer.Argument(..., help="A Cityscapes export (idda export --format cityscapes)."),
    predictions: Path = typer.Option(..., "--predictions", "-p", help="Directory of <city>_<seq>_<frame>*.png label-id predictions."),
    split: str = typer.Option("val", help="Ground-truth split: train, val or test."),
    json_out: Optional[Path] = typer.Option(None, "--json", help="Also write cityscapesScripts' result JSON here."),
) -> None:
    """Score predictions on a Cityscapes export with cityscapesScripts' pixel-level
    evaluation (its instance part, broken on numpy 2.4, is off)."""
    with user_errors():
        config = EvaluateConfig(export=str(export), predictions=str(predictions), split=split,
                                json_out=str(json_out) if json_out else None)
        typer.echo(format_report(run_evaluate(config)))


def distances(
    root: str = typer.Argument(..., help=ROOT_HELP),
    pairs: str = typer.Option("", help="Extra SOURCE:TARGET pairs of scenario codes or 'real', comma-separated (the paper's three are always tried)."),
    samples: int = typer.Option(500, help="First N frames per domain (the paper uses 500)."),
    components: int = typer.Option(50, help="PCA components kept (the paper keeps 50)."),
    domains: Optional[str] = typer.Option(None, "--domains", "-d", help=ROOT_DOMAINS_HELP + " Sampled and embedded."),
    split: list[str] = typer.Option([], help="Sample only frames of this split; repeatable."),
    chart: Optional[Path] = typer.Option(None, "--chart", help="Write a 2-D embedding of all sampled domains to this PNG."),
    seed: int = typer.Option(0, help="Seed of the feature extractor's random filters."),
    threads: int = typer.Option(4, help="Images read and featurised in parallel."),
    real: Real = None,
    real_split: RealSplits = ["val"],
    catalog: CatalogFile = None,
) -> None:
    """Domain distances as in the paper: features of the first N frames per
    domain, PCA to 50 components, Euclidean / cosine distance of the domain
    means and per-feature Bhattacharyya distance, next to the paper's values.
    With --real, a Cityscapes-layout folder is the domain 'real' (no pair
    naming it: every sampled domain is compared with it)."""
    with user_errors(), using(root_catalog(root, catalog)):
        output_root(root)
        config = DistanceConfig(
            root=root, pairs=parse_pairs(pairs), samples=samples, components=components,
            domains=domains, splits=tuple(split), seed=seed, threads=threads,
            real=str(real) if real else None, real_splits=tuple(real_split),
        )
        report = domain_distances(config)
        typer.echo(format_distance_table(report))
        if chart is not None:
            write_local(chart, embedding_png(report))
            typer.echo(f"chart: {chart}")


def card(
    root: str = typer.Argument(..., help=ROOT_HELP),
    contact_sheet: bool = typer.Option(False, "--contact-sheet", help="Render a contact sheet into <root>/preview/ and show it."),
    check: bool = typer.Option(True, "--verify/--no-verify", help="Verify the root first (every file hashed) and say in the card what verify found."),
) -> None:
    """Write a dataset card (README.md and class_shares.png) into the root.

    Exits 1 when the root fails verification (the card says so too)."""
    with user_errors(), using(root_catalog(root, None)):  # the root's declared domains: its scenarios
        output_root(root)
        result = write_card(CardConfig(root=root, contact_sheet=contact_sheet, verify=check, shape=CONFIG_SHAPE))
        typer.echo(f"wrote {result.card} ({of_held(result.frames, result.frames)}) and {result.chart}")
        if result.problems:
            found = ", ".join(f"{n} {kind}" for kind, n in sorted(result.problems.items()))
            typer.echo(f"warning: {root} failed verification ({found}), and the card says so; `idda verify {root}` "
                       "lists the damage", err=True)
        for rel in result.previews:
            typer.echo(f"linked preview {rel}")
        if result.problems:
            raise typer.Exit(code=1)  # damaged data, as verify exits


def shifts(
    root: str = typer.Argument(..., help=ROOT_HELP),
    cases: Optional[str] = typer.Option(None, help="Which of the paper's cases to run, comma-separated (default: all three, none with --pairs)."),
    pairs: str = typer.Option("", help="More SOURCE:TARGET pairs of scenario codes or 'real', comma-separated."),
    real: Real = None,
    real_split: RealSplits = ["val"],
    camvid: Optional[Path] = typer.Option(None, "--camvid", help="Instead of the cases: a folder in CamVid's layout (train/, val/ and their *annot/). Trains on --domains of the root and on CamVid train, scores both on CamVid val (11 classes) and prints the share of the real-trained mIoU kept."),
    domains: str = typer.Option("all", "--domains", "-d", help=DOMAINS_HELP + " With --camvid: the frames to train on."),
    picture: Optional[Path] = typer.Option(None, "--picture", help="With --camvid: write both networks' confusion matrices on CamVid val to this PNG."),
    steps: Optional[int] = typer.Option(None, help="Training steps per network (default 800; 600 with --camvid)."),
    batch_size: int = typer.Option(8, help="Frames per training step."),
    width: int = typer.Option(160, help="Network input width (multiple of 16; of 8 with --camvid)."),
    height: Optional[int] = typer.Option(None, help="Network input height (multiple of 16, default 96; with --camvid a multiple of 8, default 120)."),
    max_frames: Optional[int] = typer.Option(None, help="Use only the first N frames of each domain (with --camvid: of the selection and of each CamVid split)."),
    seed: int = typer.Option(0, help="Seed of the weights, batch order and flips."),
    threads: int = typer.Option(2, help="torch CPU threads."),
    device: str = typer.Option("auto", help="auto (a CUDA GPU when torch sees one), cpu or cuda."),
    json_out: Path = typer.Option(Path("shifts.json"), "--json", help="Write the full results (per-class IoU) here."),
    ceiling: Optional[Path] = typer.Option(None, "--ceiling", help="With --camvid: take the CamVid-trained side from an earlier run's --json (or docs/worlds.json) instead of training it; it must have been trained as this run would (steps, size, seed, threads, device, frames)."),
    catalog: CatalogFile = None,
) -> None:
    """The paper's domain-shift table: train a small segmentation net from scratch
    on each source domain (T01_CS_A, T01_CS_J, T01_HRN_A), score it on held-out
    source frames and on the target (T01_CS_J, T01_HRN_J, T07_HRN_A), and print the
    share of mIoU kept next to the paper's. --pairs adds any pair of declared domains, or
    of one and 'real', a Cityscapes-layout folder (--real) scored on its gtFine labelIds.
    --camvid measures synthetic to real instead (docs/realism.md).
    Needs PyTorch: pip install -e '.[analysis]'."""
    import json


    with user_errors(), using(root_catalog(root, catalog)):
        from analysis.distances import parse_pairs
        from analysis.shift_table import CASE_BY_NAME, ShiftConfig, format_shift_table, require_torch, run_shifts

        require_torch()  # the analysis extra: say so before reading any data
        output_root(root)
        for path in (json_out, picture):  # fail before minutes of training, not after
            if path is not None and not path.parent.is_dir():
                raise ValueError(f"cannot write {path}: directory {path.parent} does not exist")
        if camvid is not None:
            if cases or pairs.strip() or real:
                raise ValueError("--camvid measures on its own: leave out --cases, --pairs and --real")
            from analysis.camvid import TransferConfig, confusion_picture, format_transfer, run_transfer

            transfer = run_transfer(TransferConfig(
                root=root, camvid=str(camvid), domains=domains, steps=steps or 600, batch_size=batch_size,
                width=width, height=height or 120, max_frames=max_frames, seed=seed, threads=threads, device=device),
                ceiling_from=None if ceiling is None else str(ceiling))
            typer.echo(format_transfer(transfer))
            write_local(json_out, (json.dumps(transfer.to_json(), indent=1) + "\n").encode())
            typer.echo(f"wrote {json_out}")
            if picture is not None:
                confusion_picture(transfer, picture)
                typer.echo(f"confusion picture: {picture}")
            return
        if picture is not None or domains != "all" or ceiling is not None:
            raise ValueError("--picture, --domains and --ceiling go with --camvid")
        if cases is None:
            cases = "" if pairs.strip() else ",".join(CASE_BY_NAME)
        config = ShiftConfig(
            root=root, cases=tuple(c.strip() for c in cases.split(",") if c.strip()), pairs=parse_pairs(pairs),
            real=str(real) if real else None, real_splits=tuple(real_split), steps=steps or 800,
            batch_size=batch_size, width=width, height=height or 96, max_frames=max_frames, seed=seed,
            threads=threads, device=device,
        )
        report = run_shifts(config)
        typer.echo(format_shift_table(report))
        write_local(json_out, (json.dumps(report.to_json(), indent=1) + "\n").encode())
        typer.echo(f"wrote {json_out}")


def view(
    root: str = typer.Argument(..., help=ROOT_HELP),
    scenario: str = typer.Option(..., "--scenario", help="The episode's scenario code, e.g. T01_CS_A."),
    episode: int = typer.Option(..., "--episode", help="The episode's index in its scenario."),
    out: Optional[Path] = typer.Option(None, "--out", help="The rerun recording to write (.rrd); open it with `rerun FILE.rrd`."),
    spawn: bool = typer.Option(False, "--spawn", help="Open the rerun viewer and stream the episode to it."),
    stride: Optional[int] = typer.Option(None, "--stride", help="Depth point cloud: every N-th pixel (default: at most 200,000 points a frame)."),
    picture: Optional[Path] = typer.Option(None, "--picture", help="Also draw one frame of the recording (read back from --out) as a PNG, for places without a display."),
    frame: Optional[int] = typer.Option(None, "--frame", help="The frame --picture draws (default: the middle one)."),
    catalog: CatalogFile = None,
) -> None:
    """Look at an episode in rerun: per frame the RGB, the semantic labels, the depth as a
    point cloud in world coordinates, the camera pose and frustum, the 3D boxes and the
    condition columns as time series (needs rerun-sdk: pip install -e '.[view]')."""
    with user_errors(), using(root_catalog(root, catalog)):
        if picture is not None and out is None:
            raise ValueError("--picture draws from the recording: give --out FILE.rrd too")
        output_root(root)
        report = run_view(ViewConfig(root=root, scenario=scenario, episode=episode,
                                     out=None if out is None else str(out), spawn=spawn, stride=stride))
        where = f" to {report.out}" if report.out else ""
        typer.echo(f"recorded {count(report.frames, 'frame')} of {scenario} episode {episode}{where}")
        if picture is not None:
            write_local(picture, picture_png(read_recording(report.out), frame))
            typer.echo(f"drew {picture}")


COMMANDS = {"export": export, "evaluate": evaluate, "distances": distances, "card": card, "shifts": shifts,
            "view": view}


def register(app: typer.Typer) -> None:
    """Add the commands to ``app`` (once; calling again changes nothing)."""
    present = {c.name or (c.callback.__name__ if c.callback else None) for c in app.registered_commands}
    for name, function in COMMANDS.items():
        if name not in present:
            app.command(name=name)(function)
