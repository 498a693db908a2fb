"""Domain files on the command line: ``--catalog FILE`` and ``idda catalog show`` (docs/catalog.md).

Every command that takes ``--domains`` takes ``--catalog FILE`` too: the
file's towns, weathers and viewpoints are added to the built-in ones (or
override them) while the command runs. A command on an output root puts the
root's own entries (recorded in its run.json) in force first, so a root is
resumed, queried and verified without the file.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

from domains.catalog import BUILTIN, catalog_for
from domains.catalog_file import CatalogError, catalog_toml, with_file
from domains.rigs import DEFAULT_RIG, run_rig
from pipeline.cli.common import user_errors
from pipeline.settings import CONFIG_SHAPE, RECORDED_DEFAULTS, PlanConfig
from render_workers.worlds.styles import STYLE_BY_NAME
from roots.run_file import RunRecordError, read_record
from storage import Storage, StorageError

CATALOG_HELP = ("Domain file (TOML) whose towns, weathers and viewpoints are added to the built-in ones or "
                "override them (docs/catalog.md); select them all with --domains catalog.")
CatalogFile = Annotated[Optional[Path], typer.Option("--catalog", help=CATALOG_HELP)]
RIG_HELP = ("Sensor rig: front (the viewpoint's camera, the default), stereo, surround, lidar64, or one a --catalog "
            "file declares with [[rig]] (docs/conventions.md).")


def domain_file(path: Path | None, base=None):
    """``base`` (default: the built-in catalog) with the entries of the domain file at ``path`` (None: none).

    CatalogError (a ValueError: one ``error:`` line) names file, entry and key."""
    base = BUILTIN if base is None else base
    if path is None:
        return base
    try:
        text = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"cannot read the domain file {path}: {getattr(exc, 'strerror', None) or exc}") from None
    catalog = with_file(base, text, str(path))
    for town in dict(catalog.layer).get("town", ()):
        if town.style not in STYLE_BY_NAME:
            raise CatalogError(f"{path}: town {town.code!r}: key 'style': unknown style {town.style!r}; "
                               f"valid styles: {', '.join(STYLE_BY_NAME)}")
    return catalog


def recorded_layer(root: str) -> dict | None:
    """The user domain entries a root's run.json records; None where it has no (readable) record:
    the command itself then reports what is wrong with the root."""
    try:
        record = read_record(Storage.from_uri(root), CONFIG_SHAPE)
    except (RunRecordError, StorageError, OSError, ValueError):
        return None
    return (record or {}).get("config", {}).get("catalog")


def root_recorded(root: str, key: str):
    """A root's recorded ``key`` of those RECORDED_DEFAULTS lists ("pairing", "rules": roots.episode_spec): what its
    run.json records (absent: a root from before the key, its RECORDED_DEFAULTS value); a new root's
    (PlanConfig's default) where it has no record, or one that cannot be read (the command then reports
    what is wrong with it)."""
    try:
        record = read_record(Storage.from_uri(root), CONFIG_SHAPE)
    except (RunRecordError, StorageError, OSError, ValueError):
        record = None
    return getattr(PlanConfig(), key) if record is None else record["config"].get(key, RECORDED_DEFAULTS[key])


def root_pairing(root: str) -> int:
    """The pairing of a root's episode seeds (roots.episode_spec): UNPAIRED in a root from before pairing."""
    return root_recorded(root, "pairing")


def root_rules(root: str) -> int:
    """The rules of a root (roots.episode_spec): OLD_RULES in a root from before them."""
    return root_recorded(root, "rules")


def root_rig(root: str, name: str | None, path: Path | None) -> str:
    """The rig a run on ``root`` uses (``PlanConfig.rig``): ``name`` (built-in, or declared by ``[[rig]]`` in the
    domain file at ``path``), else the root's recorded one (a new root: front)."""
    if name is None:
        return root_recorded(root, "rig")
    return chosen_rig(name, path)


def chosen_rig(name: str | None, path: Path | None) -> str:
    """What a run records as its rig (``PlanConfig.rig``) for ``--rig name`` (None: the default, front), a
    built-in rig or one the domain file at ``path`` declares; RigError (one ``error:`` line) if there is none."""
    if name is None:
        return DEFAULT_RIG
    return run_rig(name, path.read_text(encoding="utf-8") if path is not None else None, str(path))


def root_catalog(root: str | None, path: Path | None):
    """The catalog a command on ``root`` works with: the root's recorded entries, then the file's."""
    return domain_file(path, catalog_for(recorded_layer(root) if root else None))


catalog_app = typer.Typer(help="The domain catalog: towns, weathers and viewpoints (docs/catalog.md).",
                          no_args_is_help=True)


@catalog_app.command("show")
def show(
    catalog: CatalogFile = None,
    root: Optional[str] = typer.Option(None, "--root", help="Show the catalog an output root was made with (its run.json)."),
) -> None:
    """Print the resolved catalog as a domain file: every entry with every parameter, each
    under a comment giving its meaning, unit and range. The output loads back as the same catalog."""
    with user_errors():
        typer.echo(catalog_toml(root_catalog(root, catalog)), nl=False)


def register(app: typer.Typer) -> None:
    """Add the ``catalog`` group to ``app`` (once)."""
    if not any(group.name == "catalog" for group in app.registered_groups):
        app.add_typer(catalog_app, name="catalog")
