"""The ``idda`` command line: thin typer commands that build one config and
call one function. Errors reach the user as one line and exit code 2."""

from __future__ import annotations

import contextlib
import logging
from pathlib import Path
from typing import Iterator, Optional

import typer

from pipeline.planner import PlanConfig, make_plan

app = typer.Typer(
    help="Produce large multi-domain synthetic driving datasets (IDDA-style).\n\n"
    "Domains are selected with one grammar everywhere: 'all'; scenario codes such as "
    "T01_CS_A,T07_HRN_* ; or axis filters such as 'towns=T01-T06 weathers=CN viewpoints=A,M'.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
)


@app.callback()
def _root() -> None:
    """Produce large multi-domain synthetic driving datasets (IDDA-style)."""

DOMAINS_HELP = (
    "Scenarios to use: 'all', codes like T01_CS_A (parts may be *), or filters like "
    "'towns=T01-T06 weathers=CN viewpoints=A,M'."
)


class UserError(Exception):
    """An error the user can fix; shown as one line."""


@contextlib.contextmanager
def user_errors() -> Iterator[None]:
    """Turn expected failures into one readable line and exit code 2."""
    try:
        yield
    except typer.Exit:
        raise
    except (ValueError, UserError, OSError, ImportError) as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(code=2) from None
    except Exception as exc:  # storage and Ray errors arrive as their own types
        if type(exc).__name__ in {"StorageError", "ManifestError", "RunConfigError"}:
            typer.echo(f"error: {exc}", err=True)
            raise typer.Exit(code=2) from None
        raise


def _plan_config(
    domains: str, scale: Optional[float], frames_per_scenario: Optional[int], width: int, height: int, seed: int
) -> PlanConfig:
    return PlanConfig(
        domains=domains,
        scale=scale,
        frames_per_scenario=frames_per_scenario,
        width=width,
        height=height,
        seed=seed,
    )


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
    return "\n".join(lines)


@app.command()
def plan(
    domains: str = typer.Option("all", "--domains", "-d", help=DOMAINS_HELP),
    scale: Optional[float] = typer.Option(None, help="Fraction (0, 1] of the paper's full-scale frame counts."),
    frames_per_scenario: Optional[int] = typer.Option(None, help="Frames per scenario (instead of --scale)."),
    width: int = typer.Option(1920, help="Image width in pixels."),
    height: int = typer.Option(1080, help="Image height in pixels."),
    seed: int = typer.Option(0, help="Run seed; every episode's seed derives from it."),
    out: Optional[Path] = typer.Option(None, help="Write the plan as Parquet (one row per episode)."),
) -> None:
    """Expand a domain selection into shards and episodes, and print them.

    Without --scale or --frames-per-scenario the plan is full scale: all 105
    scenarios hold the paper's 1,006,800 frames.
    """
    with user_errors():
        the_plan = make_plan(_plan_config(domains, scale, frames_per_scenario, width, height, seed))
        typer.echo(format_plan_table(the_plan))
        if out is not None:
            from pipeline.planio import write_plan

            write_plan(the_plan, out)
            typer.echo(f"wrote {len(the_plan.episodes):,} episodes to {out}")


def main() -> None:
    """Entry point of the ``idda`` script."""
    logging.basicConfig(level=logging.WARNING, format="%(levelname)s %(name)s: %(message)s")
    app()


if __name__ == "__main__":
    main()
