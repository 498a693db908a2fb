"""The command line: the Typer app (``app``), its shared options (``common``) and the data commands (``data``)."""

from pipeline.cli.app import app, main

__all__ = ["app", "main"]
