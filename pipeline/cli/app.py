"""The ``idda`` command line: thin typer commands that build one config and
call one function. Errors reach the user as one line and exit code 2."""

from __future__ import annotations

import logging
import os
import sys
import threading
from dataclasses import replace
from pathlib import Path
from typing import NoReturn, Optional

import typer

from domains.catalog import using
from domains.rigs import rig_named
from domains.selection import parse_selection
from manifests import query as q
from manifests.stats import bar_chart_png, format_share_table, share_table
from pipeline.cli import data as cli_data, domain_files as cli_domains
from pipeline.cli.domain_files import (
    RIG_HELP, CatalogFile, chosen_rig, domain_file, root_catalog, root_pairing, root_rig, root_rules,
)
from pipeline.cli.progress import (
    ProgressDisplay, VerifyDisplay, format_head_lost, format_interrupted, format_outage, format_produce_report,
    stop_signals,
    verify_advice,
)
from pipeline.cli.common import (
    DOMAINS_HELP, ROOT_HELP, Domains, HasClass, MaxCondition, MinCondition, MinShare, OneLineUsageErrors, PerScenario,
    Preset, SampleSeed, Splits, Total, build_query, count, of_held, of_held_frames, of_held_sensors, output_root,
    user_errors, write_local,
)
from outputs.table import CAMERA_OUTPUTS, DEFAULT_OUTPUTS, OUTPUTS, parse_outputs
from manifests.reader import read_manifest, require_outputs, scan_manifest
from pipeline.driver import HeadLost, ProduceInterrupted, RendererCrashes, StorageOutage, produce as run_produce
from pipeline.plan_file import write_plan
from pipeline.planner import make_plan
from pipeline.settings import CONFIG_SHAPE, PlanConfig, ProduceConfig, RunConfig
from pipeline.status import format_duration, root_status
from pipeline.verify_ray import choose_runner
from render_workers.worlds.registry import check_world
from roots.lease import ttl_from_env as lease_ttl_from_env
from roots.verify import Scope, parse_since, verify as run_verify

app = typer.Typer(
    cls=OneLineUsageErrors,
    help="Produce large multi-domain synthetic driving datasets (IDDA-style).\n\n"
    "Domains are selected with one grammar everywhere: 'all'; scenario codes such as "
    "T01_CS_A,T07_HRN_* ; or axis filters such as 'towns=T01-T06 weathers=CN viewpoints=A,M'.\n\n"
    "Exit codes: 0 done; 1 the data has a problem (verify found damage, episodes failed) or produce stopped "
    "because its storage or its Ray cluster's head went away (run it again to resume); "
    "2 a usage error, including a selection that matches no frames, or an environment that cannot render "
    "(render workers crashing on every episode); 130 interrupted (Ctrl-C); "
    "143 and 129 stopped by SIGTERM and SIGHUP (resume by running the same command again).",
    no_args_is_help=True,
    context_settings={"help_option_names": ["-h", "--help"]},
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
)


def _print_version(value: bool) -> None:
    if value:
        from importlib.metadata import version

        typer.echo(f"idda {version('idda-pipeline')}")
        raise typer.Exit()


@app.callback()
def _root(
    version: bool = typer.Option(
        False, "--version", "-V", callback=_print_version, is_eager=True, help="Print the version and exit."
    ),
) -> None:
    """Produce large multi-domain synthetic driving datasets (IDDA-style)."""


def format_plan_table(plan) -> str:
    """One line per scenario (episodes, frames), then totals."""
    rows = [("scenario", "episodes", "frames", "frames/episode")]
    for code, episodes in plan.by_scenario().items():
        lengths = [e.frames for e in episodes]
        span = f"{min(lengths)}-{max(lengths)}" if min(lengths) != max(lengths) else str(lengths[0])
        rows.append((code, str(len(episodes)), f"{sum(lengths):,}", span))
    rows.append(
        (
            f"total ({len(plan.scenarios())} scenarios)",
            f"{len(plan.episodes):,}",
            f"{plan.total_frames:,}",
            "",
        )
    )
    widths = [max(len(r[i]) for r in rows) for i in range(4)]
    lines = []
    for i, row in enumerate(rows):
        if i == len(rows) - 1:
            lines.append("-" * (sum(widths) + 6))
        lines.append(
            f"{row[0]:<{widths[0]}}  {row[1]:>{widths[1]}}  {row[2]:>{widths[2]}}  {row[3]:>{widths[3]}}"
        )
    cfg = plan.config
    lines.append(f"resolution {cfg.width}x{cfg.height}, seed {cfg.seed}")
    lines.append(format_rig_line(rig_named(cfg.rig), plan.total_frames, cfg.width, cfg.height))
    return "\n".join(lines)


def format_rig_line(rig, frames: int, width: int, height: int) -> str:
    """The rig's sensors (a camera of its own size with it), and the frames as sensor frames: every
    sensor of the rig sees every frame."""
    own = {s.name: "" if not (s.width or s.height) else " {}x{}".format(*s.size(width, height)) for s in rig.sensors}
    sensors = ", ".join(f"{s.name} ({s.kind}{own[s.name]})" for s in rig.sensors)
    return (f"rig {rig.name}: {count(len(rig.sensors), 'sensor')}, {sensors}; "
            f"{count(frames, 'frame')} = {count(frames * len(rig.sensors), 'sensor frame')}")


@app.command()
def plan(
    domains: str = typer.Option("all", "--domains", "-d", help=DOMAINS_HELP),
    scale: Optional[float] = typer.Option(None, help="Fraction (0, 1] of the paper's full-scale frame counts."),
    frames_per_scenario: Optional[int] = typer.Option(None, help="Frames per scenario (instead of --scale)."),
    width: int = typer.Option(1920, help="Image width in pixels."),
    height: int = typer.Option(1080, help="Image height in pixels."),
    seed: int = typer.Option(0, help="Run seed; every episode's seed derives from it."),
    out: Optional[Path] = typer.Option(None, help="Write the plan as Parquet (one row per episode)."),
    catalog: CatalogFile = None,
    rig: Optional[str] = typer.Option(None, "--rig", help=RIG_HELP + " The plan lists its sensors and counts sensor frames."),
) -> None:
    """Expand a domain selection into shards and episodes, and print them.

    Without --scale or --frames-per-scenario the plan is full scale: all 105
    scenarios hold the paper's 1,006,800 frames.
    """
    with user_errors():
        layer = domain_file(catalog).layer_json()  # a bad file is reported before its rigs are read
        the_plan = make_plan(PlanConfig(domains=domains, scale=scale, frames_per_scenario=frames_per_scenario, width=width,
                                        height=height, seed=seed, catalog=layer, rig=chosen_rig(rig, catalog)))
        typer.echo(format_plan_table(the_plan))
        if out is not None:
            write_plan(the_plan, out)
            typer.echo(f"wrote {len(the_plan.episodes):,} episodes to {out}")


@app.command()
def produce(
    domains: str = typer.Option("all", "--domains", "-d", help=DOMAINS_HELP),
    out: str = typer.Option("output", "--out", "-o", help="Output root: a local path or s3://bucket/prefix."),
    scale: Optional[float] = typer.Option(None, help="Fraction (0, 1] of the paper's full-scale frame counts; 1 is the full dataset."),
    frames_per_scenario: Optional[int] = typer.Option(None, help="Frames per scenario (default 2 when --scale is not given)."),
    width: int = typer.Option(1920, help="Image width in pixels."),
    height: int = typer.Option(1080, help="Image height in pixels."),
    seed: int = typer.Option(0, help="Run seed; every episode's seed derives from it."),
    world: str = typer.Option("procedural", help="World builder: procedural (the seven towns) or test (simple test world)."),
    address: Optional[str] = typer.Option(None, help="Ray cluster address (default: $RAY_ADDRESS, else a local cluster)."),
    workers: Optional[int] = typer.Option(None, help="CPUs for a local Ray cluster (default: all cores)."),
    gpus_per_task: float = typer.Option(0.0, help="GPU share per render task, e.g. 0.25 to run four per GPU."),
    max_retries: int = typer.Option(3, help="Retries per episode after a worker, node or renderer failure."),
    extend: bool = typer.Option(False, "--extend", help="Allow a different selection or size than the root was made with. Episodes made longer are rendered again whole; in a shifting weather (e.g. CNtoNT) their earlier frames change, since a shift runs over its episode's length."),
    repair: bool = typer.Option(False, "--repair", help="Verify first and re-render exactly the damaged episodes."),
    outputs: str = typer.Option(",".join(DEFAULT_OUTPUTS), "--outputs", help=f"Outputs to write, comma-separated: any of {', '.join(CAMERA_OUTPUTS)}. A root keeps the outputs it was made with."),
    rgb_format: str = typer.Option("png", "--rgb-format", help="File format of the rgb output: png (lossless, the default) or jpg (quality 95, the released IDDA format; about a quarter of the bytes). A root keeps its format."),
    catalog: CatalogFile = None,
    frame_interval: float = typer.Option(3.0, "--frame-interval", metavar="SECONDS", help="Simulated seconds between frames: 3 (the paper's sparse sampling, the default) or e.g. 0.1 for a 10 Hz video-like episode. A root keeps its interval."),
    rig: Optional[str] = typer.Option(None, "--rig", help=RIG_HELP + " A root keeps its rig."),
) -> None:
    """Render the selected scenarios into an output root (resumable).

    Re-running the same command skips finished episodes: kill it at any time
    and run it again. Full scale is --scale 1 (1,006,800 frames at 1920x1080).
    """
    with user_errors():
        if scale is None and frames_per_scenario is None:
            frames_per_scenario = 2
        # the root's recorded domain entries (resume and extend need no file), then the file's
        layer = root_catalog(out, catalog).layer_json()
        plan_cfg = PlanConfig(domains=domains, scale=scale, frames_per_scenario=frames_per_scenario, width=width,
                              height=height, seed=seed, outputs=parse_outputs(outputs), rgb_format=rgb_format,
                              catalog=layer, frame_interval_s=frame_interval, pairing=root_pairing(out),
                              rules=root_rules(out), rig=root_rig(out, rig, catalog))
        config = ProduceConfig(
            run=RunConfig(plan=plan_cfg, world=world),
            out=out,
            address=address,
            workers=workers,
            gpus_per_task=gpus_per_task,
            max_retries=max_retries,
            extend=extend,
            repair=repair,
            lease_ttl_s=lease_ttl_from_env(),
        )
        bar = ProgressDisplay()
        with stop_signals() as stopped:
            try:
                report = run_produce(config, progress=bar.update, on_head_lost=lambda lost: _end_head_lost(bar, lost))
            except ProduceInterrupted as stop:
                bar.close()
                typer.echo(format_interrupted(stop.report, stopped.get("name", "interrupted")), err=True)
                raise typer.Exit(code=stopped.get("code", 130)) from None
            except StorageOutage as outage:
                from storage import Storage

                bar.close()
                typer.echo(format_outage(outage, Storage.from_uri(out).endpoint), err=True)
                raise typer.Exit(code=1) from None
            except HeadLost as lost:  # the cluster is gone; what finished is committed
                _end_head_lost(bar, lost)
            except RendererCrashes as crashes:  # the environment cannot render: no retry helps
                bar.close()
                typer.echo(f"error: {crashes}", err=True)
                raise typer.Exit(code=2) from None
            except KeyboardInterrupt:  # before or after rendering: nothing half done to report
                bar.close()
                typer.echo(f"{stopped.get('name', 'interrupted')}: run the same command again to resume", err=True)
                raise typer.Exit(code=stopped.get("code", 130)) from None
            finally:
                bar.close()
        typer.echo(format_produce_report(report))
        if not report.ok:
            raise typer.Exit(code=1)


_HEAD_LOST = threading.Lock()


def _end_head_lost(bar, lost: HeadLost) -> NoReturn:
    """One line for a run whose Ray head is gone, then exit 1 at once: from the driver's loop, or from its
    head watch when the loop is blocked inside Ray (which would abort the process 60 s after the head went,
    with a line of its own). Ray's exit handler is skipped too: its shutdown waits for the dead head.
    Whichever comes first says it; the other waits here for the end."""
    with _HEAD_LOST:
        bar.close()
        typer.echo(format_head_lost(lost), err=True)
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(1)


@app.command()
def status(root: str = typer.Argument(..., help=ROOT_HELP)) -> None:
    """Done / pending episodes and frames per scenario, and the time left."""
    with user_errors():
        st = root_status(output_root(root))
        for part in st.misnamed:
            typer.echo(f"warning: {part}: counted by its rows; `idda verify` and `idda produce --repair` mend it",
                       err=True)
        w = max([10, *(len(s.scenario) for s in st.scenarios)])  # a declared code may be longer than T01_HRN_A
        typer.echo(f"{'scenario':<{w}} {'episodes':>13} {'frames':>17}")
        for s in st.scenarios:
            mark = "done" if s.frames_done == s.frames_total else ""
            typer.echo(f"{s.scenario:<{w}} {s.episodes_done:>6}/{s.episodes_total:<6} {s.frames_done:>8}/{s.frames_total:<8} {mark}")
        pct = 100 * st.frames_done / max(st.frames_total, 1)
        line = f"{st.uri}: {st.frames_done:,} of {st.frames_total:,} frames done ({pct:.1f}%)"
        if st.frames_done < st.frames_total:
            eta = st.eta_s
            line += f"; about {format_duration(eta)} left at the last run's {st.frames_per_s:.2f} frames/s" if eta is not None else "; no rate measured yet"
        if st.extra_episodes:
            line += f"; {st.extra_episodes} more episode(s) from earlier --extend runs"
        typer.echo(line)


@app.command()
def verify(
    root: str = typer.Argument(..., help=ROOT_HELP),
    domains: Optional[str] = typer.Option(None, "--domains", "-d", help="Verify only these scenarios. " + DOMAINS_HELP),
    since: Optional[str] = typer.Option(None, help="Verify only episodes written since then: an age (30m, 2h, 3d) or an ISO time (UTC unless it says)."),
    address: Optional[str] = typer.Option(None, help="Ray cluster address (default: $RAY_ADDRESS, else a local cluster)."),
    workers: Optional[int] = typer.Option(None, help="CPUs for a local Ray cluster (default: all cores)."),
    use_ray: Optional[bool] = typer.Option(None, "--ray/--no-ray", help="Check on Ray, or in this process (default: Ray for large roots or with an address)."),
    threads: int = typer.Option(8, help="Files checked in parallel per task."),
    strict: bool = typer.Option(False, "--strict", help="Fail (exit 1) on foreign files too: files whose names are not of the root's layout."),
    catalog: CatalogFile = None,
) -> None:
    """Recompute every checksum; report missing, corrupt and extra files.

    Runs as Ray tasks, one per scenario. Exits 1 when anything is wrong;
    `idda produce --repair` fixes it. Frames a running producer is writing
    are reported as in progress, not as damage. Files whose names are not of
    the root's layout are listed as foreign (left alone; --strict fails on them).
    Verify never changes the root.
    """
    with user_errors():
        with using(root_catalog(root, catalog)):
            chosen = None if domains is None else frozenset(s.code for s in parse_selection(_non_empty(domains)))
        scope = Scope(scenarios=chosen, since=None if since is None else parse_since(since))
        storage = output_root(root)
        runner = choose_runner(address=address, workers=workers, use_ray=use_ray)
        display = VerifyDisplay()
        try:
            report = run_verify(storage, threads=threads, progress=display.update, scope=scope, runner=runner,
                                shape=CONFIG_SHAPE)
        finally:
            display.close()
        for p in report.problems[:50]:
            typer.echo(f"{p.kind:<8} {p.path}" + (f"  ({p.detail})" if p.detail else ""))
        if len(report.problems) > 50:
            typer.echo(f"... and {len(report.problems) - 50} more")
        for rel in report.foreign[:50]:
            typer.echo(f"foreign  {rel}")
        if len(report.foreign) > 50:
            typer.echo(f"... and {len(report.foreign) - 50} more foreign")
        mb = report.bytes_checked / 1e6
        rate = mb / report.seconds if report.seconds else 0.0
        summary = f"checked {report.files_checked:,} files, {mb:,.1f} MB in {report.seconds:.1f} s ({rate:.0f} MB/s)"
        if report.in_progress:
            summary += (f"; {count(len(report.in_progress), 'episode')} in progress (a producer is writing them; "
                        "verify again when it has finished)")
        if report.foreign:
            summary += (f"; {count(len(report.foreign), 'foreign file')} (not of the root's layout: verify and repair "
                        "leave them alone" + ("" if strict else "; --strict fails on them") + ")")
        if report.ok and not (strict and report.foreign):
            typer.echo(f"OK: {summary}")
            return
        if report.ok:  # only foreign files, under --strict
            typer.echo(f"FAILED (--strict): {summary}.")
            raise typer.Exit(code=1)
        counts = ", ".join(f"{n} {kind}" for kind, n in sorted(report.counts().items()))
        typer.echo(f"FAILED: {counts}; {summary}. {verify_advice(report)}")
        raise typer.Exit(code=1)


def _non_empty(domains: str) -> str:
    if not domains.strip():
        raise ValueError("--domains is empty; give scenarios, or leave the option out to verify all of them")
    return domains


@app.command()
def query(
    root: str = typer.Argument(..., help=ROOT_HELP),
    preset: Preset = None,
    domains: Domains = None,
    split: Splits = [],
    episode: list[int] = typer.Option([], help="Keep this episode index; repeatable."),
    sensor: list[str] = typer.Option([], "--sensor", help="Keep the frames of this sensor of the root's rig (e.g. left, frontleft, lidar; the default rig's camera is front); repeatable."),
    has_class: HasClass = [],
    min_share: MinShare = [],
    min_condition: MinCondition = [],
    max_condition: MaxCondition = [],
    paired: Optional[str] = typer.Option(None, "--paired", metavar="WEATHERS", help="Comma-separated weathers, e.g. CN,HRN,SN: keep the frames present under all of them (the same scene in a paired root), one group per frame, aligned by town, viewpoint, episode and frame."),
    per_scenario: PerScenario = None,
    total: Total = None,
    seed: SampleSeed = None,
    out: Optional[Path] = typer.Option(None, help="Write the frames: .txt/.lst (file list), .csv or .parquet."),
    fmt: Optional[str] = typer.Option(None, "--format", help="list, csv or parquet (default: from --out's suffix)."),
    outputs: str = typer.Option("rgb,semantic_raw", help="Outputs listed per frame in file lists (CSV and Parquet hold every manifest column)."),
    catalog: CatalogFile = None,
) -> None:
    """Filter frames and draw seeded stratified samples, e.g. --preset best-case."""
    with user_errors(), using(root_catalog(root, catalog)):
        the_query = build_query(preset, domains, split, has_class, min_share, per_scenario, total, seed, tuple(episode),
                                min_condition, max_condition)
        if paired is not None:
            chosen = tuple(w.strip() for w in paired.split(",") if w.strip())
            the_query = replace(the_query, paired=chosen)
            the_query.validate()
        if sensor:
            the_query = replace(the_query, sensors=tuple(sensor))
            the_query.validate()
        storage = output_root(root)
        result, (held, held_rows) = scan_manifest(storage, lambda dataset: (q.run_query(dataset, the_query),
                                                                             q.count_held(dataset)))
        for code, missing in sorted(result.shortfall.items()):
            typer.echo(f"warning: {code} has {missing} frame(s) fewer than asked for", err=True)
        if result.split_apart:
            typer.echo(f"warning: left out {result.split_apart:,} frame(s) whose weathers lie in different splits "
                       "(a root made before splits were drawn per scene)", err=True)
        if len(result.table) == 0:
            raise ValueError(f"no frames in {storage.uri} match the query ({of_held(result.matched, held)} "
                             "match the filters)")
        chosen = parse_outputs(outputs)
        if out is not None:
            fmt = fmt or q.FORMAT_BY_SUFFIX.get(out.suffix)
            if fmt is None:
                raise ValueError(f"cannot tell the format of {out}; use --format list|csv|parquet")
            if fmt == "list":
                require_outputs(result.table, chosen, storage.uri)
            data = q.encode_result(result.table, fmt, chosen)
            write_local(out, data)
        counts = q.frames_per_scenario(result.table)  # in a rig's root: frames, not its rows (sensor frames)
        w = max([10, *map(len, counts)])  # a declared code may be longer than T01_HRN_A
        for code, n in sorted(counts.items()):
            typer.echo(f"{code:<{w}} {n:>8}")
        where = f"; wrote {out}" if out is not None else ""
        chosen_frames = sum(counts.values())
        typer.echo(f"{chosen_frames:,} frames selected of {result.matched:,} matching the filters "
                   f"({of_held_sensors(chosen_frames, held, len(result.table), held_rows)}){where}")


@app.command()
def stats(
    root: str = typer.Argument(..., help=ROOT_HELP),
    domains: Domains = None,
    per_scenario: bool = typer.Option(False, "--per-scenario", help="One table and one chart panel per scenario instead of overall."),
    chart: Path = typer.Option(Path("class_shares.png"), help="Write the log-scale bar chart PNG here (default: class_shares.png in the current directory; never into the root)."),
    catalog: CatalogFile = None,
) -> None:
    """Class pixel shares as a table and a log-scale bar chart (paper's Fig. pixeldistr)."""
    with user_errors(), using(root_catalog(root, catalog)):
        storage = output_root(root)
        if storage.is_local and chart.resolve().is_relative_to(Path(storage.path()).resolve()):
            raise ValueError(f"the chart {chart} would land inside the output root {storage.uri}; "
                             "pass --chart with a path outside it")
        manifest = read_manifest(storage)
        table = q.filter_frames(manifest, q.Query(domains=domains))
        if len(table) == 0:
            raise ValueError(f"{storage.uri} has no frames" + (f" for {domains!r}" if domains else "") + " yet")
        shares = share_table(table, by_scenario=per_scenario)
        typer.echo(format_share_table(shares))
        write_local(chart, bar_chart_png(shares, title=f"Class pixel shares, {q.count_frames(table):,} frames"))
        typer.echo(f"chart: {chart} ({of_held_frames(table, manifest)})")


@app.command()
def preview(
    out: Path = typer.Option(..., "--out", "-o", help="Directory for the contact sheet(s) and the six-output strip."),
    domains: str = typer.Option("weathers=CN", "--domains", "-d", help=DOMAINS_HELP),
    width: int = typer.Option(480, help="Width of each rendered frame."),
    height: int = typer.Option(270, help="Height of each rendered frame."),
    seed: int = typer.Option(0, help="Run seed."),
    world: str = typer.Option("procedural", help="World builder: procedural or test."),
    catalog: CatalogFile = None,
) -> None:
    """Render one frame per scenario into a contact sheet (rows = viewpoints,
    columns = towns, one sheet per weather) plus one frame's six outputs."""
    from render_workers.render.preview import write_preview  # deferred: the renderer (trimesh, scipy) only to render

    with user_errors(), using(domain_file(catalog)) as in_force:
        PlanConfig(domains=domains, width=width, height=height, seed=seed, frames_per_scenario=1,
                   catalog=in_force.layer_json()).validate()
        check_world(world)
        out.mkdir(parents=True, exist_ok=True)
        codes = [s.code for s in parse_selection(domains)]
        paths = write_preview(out, codes, width, height, seed, world=world)
        for path in paths:
            typer.echo(f"wrote {path}")


cli_data.register(app)  # export, distances, card
cli_domains.register(app)  # catalog show


def main() -> None:
    """Entry point of the ``idda`` script."""
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    app()


if __name__ == "__main__":
    main()
