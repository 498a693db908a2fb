"""``python -m pipeline.cli``: the same as the ``idda`` command."""

from pipeline.cli.app import main

main()
