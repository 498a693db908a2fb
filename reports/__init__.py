"""Generators of the docs that `make report` writes (docs/worlds.md and its pictures)."""
