"""What every ``idda`` command shares: error handling, file writing and the
query options. ``pipeline.cli`` and ``pipeline.cli.data`` both import this
module and never each other."""

from __future__ import annotations

import contextlib
import os
import sys
from pathlib import Path
from typing import Annotated, Iterator, Optional

import typer
from typer.core import TyperGroup

from manifests import query as q
from roots.contract import require_root
from storage import Storage

try:  # typer 0.2x vendors click; its exceptions are that copy's
    from typer._click import exceptions as click_errors
except ImportError:  # older typer: click itself
    from click import exceptions as click_errors

from roots.lease import LeaseError
from domains.selection import SELECTION_HELP
from manifests.part_file import ManifestError
from pipeline.provenance import RunConfigError
from storage import StorageError

ROOT_HELP = "Output root (path or s3:// URI)."
DOMAINS_HELP = SELECTION_HELP
ROOT_DOMAINS_HELP = SELECTION_HELP + " Default: every scenario the root holds."  # commands that read a root

# The query options `idda query` and `idda export` share, declared once.
Preset = Annotated[Optional[str], typer.Option(help="Ready-made subset: best-case or worst-case (the paper's).")]
Domains = Annotated[Optional[str], typer.Option("--domains", "-d", help=ROOT_DOMAINS_HELP)]
Splits = Annotated[list[str], typer.Option("--split", help="Keep frames of this split (train, val, test); repeatable.")]
HasClass = Annotated[list[str], typer.Option("--has", help="Keep frames containing this class, e.g. --has rider; repeatable.")]
MinShare = Annotated[list[str], typer.Option(
    "--min-share", help="CLASS=SHARE: keep frames where the class covers at least SHARE (0-1); repeatable.")]
MinCondition = Annotated[list[str], typer.Option(
    "--min-condition", help="NAME=VALUE: keep frames whose condition NAME is at least VALUE, e.g. precipitation=0.5 "
    "(sun_altitude_deg, cloudiness, precipitation, visibility_m, road_wetness, snow_cover); repeatable.")]
MaxCondition = Annotated[list[str], typer.Option(
    "--max-condition", help="NAME=VALUE: keep frames whose condition NAME is at most VALUE, e.g. "
    "sun_altitude_deg=0 for night; repeatable.")]
PerScenario = Annotated[Optional[int], typer.Option(help="Sample this many frames per scenario.")]
Total = Annotated[Optional[int], typer.Option(help="Sample this many frames in total, stratified by scenario.")]
SampleSeed = Annotated[Optional[int], typer.Option("--seed", help="Sampling seed (default 0).")]


@contextlib.contextmanager
def user_errors() -> Iterator[None]:
    """Turn expected failures into one readable line and exit code 2."""
    try:
        yield
    except typer.Exit:
        raise
    except (ValueError, OSError, ImportError, StorageError, ManifestError, RunConfigError, LeaseError) as exc:
        typer.echo(f"error: {one_line(str(exc))}", err=True)  # one line, always
        raise typer.Exit(code=getattr(exc, "exit_code", 2)) from None  # 1: damaged data
    except KeyboardInterrupt:
        typer.echo("interrupted", err=True)
        raise typer.Exit(code=130) from None


def one_line(text: str) -> str:
    return " ".join(line.strip() for line in text.splitlines() if line.strip())


class OneLineUsageErrors(TyperGroup):
    """The ``idda`` group: a usage error that click finds (an option value of
    the wrong type, an unknown option, a missing argument) is one ``error:``
    line and exit code 2, like every error the commands find themselves,
    instead of click's usage box."""

    def main(self, args=None, prog_name=None, complete_var=None, standalone_mode=True, **extra):
        if not standalone_mode:
            return super().main(args, prog_name, complete_var, standalone_mode=False, **extra)
        try:
            code = super().main(args, prog_name, complete_var, standalone_mode=False, **extra)
        except click_errors.NoArgsIsHelpError as exc:  # `idda` alone: the help, as before
            exc.show()
            sys.exit(exc.exit_code)
        except click_errors.UsageError as exc:
            where = f"; `{exc.ctx.command_path} -h` lists the options" if exc.ctx is not None else ""
            typer.echo(f"error: {one_line(exc.format_message()).rstrip('.')}{where}", err=True)
            sys.exit(2)
        except click_errors.ClickException as exc:
            typer.echo(f"error: {one_line(exc.format_message())}", err=True)
            sys.exit(exc.exit_code)
        except typer.Abort:
            typer.echo("interrupted", err=True)
            sys.exit(130)
        sys.exit(code if isinstance(code, int) else 0)


def output_root(root: str):
    """The storage of an output root; for any other path the one sentence every
    command gives (``roots.contract.require_root``)."""
    storage = Storage.from_uri(root)
    require_root(storage)
    return storage


def count(n: int, noun: str) -> str:
    """'1 frame', '2 frames', '1,000 frames'."""
    return f"{n:,} {noun}" + ("" if n == 1 else "s")


def of_held(n: int, held: int) -> str:
    """'24 of the 96 frames the root holds': what a command covered of a root."""
    return f"{n:,} of the {count(held, 'frame')} the root holds"


def of_held_sensors(frames: int, held: int, sensor_frames: int, held_sensor_frames: int) -> str:
    """``of_held``, and in a rig's root (its manifest rows, sensor frames, outnumber its frames) the sensor
    frames too: '2 of the 2 frames the root holds, 4 sensor frames of its 4'."""
    said = of_held(frames, held)
    if held_sensor_frames == held:
        return said
    return f"{said}, {count(sensor_frames, 'sensor frame')} of its {held_sensor_frames:,}"


def of_held_frames(table, manifest) -> str:
    """``of_held_sensors`` for the rows of ``table`` taken from ``manifest`` (all the root's)."""
    return of_held_sensors(q.count_frames(table), q.count_frames(manifest), len(table), len(manifest))


def write_local(path: Path, data: bytes) -> None:
    """Write ``data`` to a local file atomically (a temporary file, then a rename)."""
    if not path.parent.exists():
        raise ValueError(f"cannot write {path}: directory {path.parent} does not exist")
    tmp = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        tmp.write_bytes(data)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def _pairs(items: list[str], option: str, form: str, value_rule: str) -> tuple[tuple[str, float], ...]:
    """``NAME=NUMBER`` items of a repeatable option as (name, number) pairs; ValueError naming the option."""
    pairs = []
    for item in items:
        name, sep, value = item.rpartition("=")
        if not sep:
            raise ValueError(f"{option} takes {form}, got {item!r}")
        try:
            pairs.append((name.strip(), float(value)))
        except ValueError:
            raise ValueError(f"{option} takes {form} with {value_rule}, got {item!r}") from None
    return tuple(pairs)


def build_query(
    preset: Optional[str],
    domains: Optional[str],
    split: list[str],
    has_class: list[str],
    min_share: list[str],
    per_scenario: Optional[int],
    total: Optional[int],
    seed: Optional[int],
    episode: tuple[int, ...] = (),
    min_condition: list[str] = (),
    max_condition: list[str] = (),
):
    """A validated Query from the shared query options (as in `idda query`)."""
    shares = _pairs(min_share, "--min-share", "CLASS=SHARE", "SHARE a number in [0, 1]")
    lows = _pairs(min_condition, "--min-condition", "NAME=VALUE", "VALUE a number")
    highs = _pairs(max_condition, "--max-condition", "NAME=VALUE", "VALUE a number")
    fields = dict(
        domains=domains, splits=tuple(split) or None, episodes=tuple(episode) or None,
        classes=tuple(has_class) or None, min_share=shares or None, min_condition=lows or None,
        max_condition=highs or None, per_scenario=per_scenario, total=total, seed=seed,
    )
    if preset is not None:
        the_query = q.preset(preset, **fields)
    else:
        the_query = q.Query(**{k: v for k, v in fields.items() if v is not None})
    the_query.validate()
    return the_query
