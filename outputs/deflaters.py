"""The deflate inside every PNG file this tool writes, and which one a root keeps.

New roots deflate with libdeflate (the ``deflate`` package bundles it), at
:data:`LIBDEFLATE_LEVEL`. libdeflate is deterministic for one version, with
no state carried between calls and no CPU-specific parsing, so one frame is
one sequence of bytes however often, wherever and in whichever process it is
rendered. Roots written before used ISA-L at level 1 (``isal``): ISA-L is
faster, but it gave two different byte streams for the same input in two
worker processes (issue 21.11: same pixels, same filtered rows, one match
found in one process and not in the other), which breaks resume and verify,
since a re-rendered frame must equal its files.

Measured on two full-HD frames' seven default PNGs (T01_CN_A, T07_HRN_J;
medians of 7 alternating rounds, one core of the shared 2-core machine,
/tmp/codec_bench2.py in the issue 21 note): ISA-L level 1 34 ms and 2.053 MB
per frame; libdeflate level 2 176 ms and 1.722 MB (16% smaller files, 140 ms
more CPU per frame, on the episode's second thread); zlib level 1 194 ms and
2.204 MB.

An old root keeps its deflater (its ``run.json`` names it, see
``outputs.encoding.encoder_identity``): its workers deflate with ISA-L as
before, so resuming, extending and repairing it mix nothing. The deflater in
force is a context variable, set per frame around the encoding
(:func:`deflating_with`), so two threads may encode for two roots at once.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass
from functools import cache

from domains.catalog import lookup

LIBDEFLATE_LEVEL = 2  # libdeflate 1..12: level 2 was the fastest of 1-5 here, and smaller than ISA-L's level 1
ISAL_LEVEL = 1  # what roots written with ISA-L used


def _libdeflate(data) -> bytes:
    import deflate

    return bytes(deflate.zlib_compress(data, LIBDEFLATE_LEVEL))


def _isal(data) -> bytes:
    from isal import isal_zlib

    return isal_zlib.compress(data, ISAL_LEVEL)


@dataclass(frozen=True)
class Deflater:
    """One deflate implementation: its name in run records, its level, the package that provides it."""

    name: str
    level: int
    package: str
    compress: Callable[[bytes], bytes]  # data -> a zlib stream (RFC 1950)

    @property
    def identity(self) -> str:
        """How run.json names PNG files deflated by this (the package version included:
        another version may give other bytes)."""
        from importlib import metadata

        return f"png-sub-{self.name} level {self.level}, {self.package} {metadata.version(self.package)}"


DEFLATERS = {
    "libdeflate": Deflater("libdeflate", LIBDEFLATE_LEVEL, "deflate", _libdeflate),
    "isal": Deflater("isal", ISAL_LEVEL, "isal", _isal),  # roots written before libdeflate
}
DEFAULT_DEFLATER = "libdeflate"
_IN_FORCE: ContextVar[str] = ContextVar("png_deflater", default=DEFAULT_DEFLATER)


def deflater(name: str | None = None) -> Deflater:
    """The deflater called ``name`` (ValueError naming the known ones), or the one in force."""
    return lookup(DEFLATERS, _IN_FORCE.get() if name is None else name, "PNG deflater")


@contextmanager
def deflating_with(name: str) -> Iterator[None]:
    """PNG files written in this block (this thread or task) are deflated by ``name``."""
    token = _IN_FORCE.set(deflater(name).name)
    try:
        yield
    finally:
        _IN_FORCE.reset(token)


def deflate_png_data(data) -> bytes:
    """The zlib stream of a PNG's filtered rows, by the deflater in force."""
    return deflater().compress(data)


@cache
def deflater_named_by(png_identity: str) -> str | None:
    """The deflater whose identity is ``png_identity`` (an installed one), or None."""
    from importlib.metadata import PackageNotFoundError

    for name, row in DEFLATERS.items():
        try:
            if row.identity == png_identity:
                return name
        except PackageNotFoundError:  # not installed here: names nothing
            continue
    return None


def png_stream(png: bytes) -> bytes:
    """The zlib stream of a PNG file (its IDAT chunks joined)."""
    import struct

    out, i = [], 8
    while i + 8 <= len(png):
        (n,) = struct.unpack(">I", png[i:i + 4])
        if png[i + 4:i + 8] == b"IDAT":
            out.append(png[i + 8:i + 8 + n])
        i += 12 + n
    return b"".join(out)


def deflater_of_png(png: bytes) -> str | None:
    """The installed deflater that gives this PNG's zlib stream from its own rows
    (the default first); None if none does (damaged, or another deflater's)."""
    import zlib

    stream = png_stream(png)
    try:
        rows = zlib.decompress(stream)
    except zlib.error:
        return None
    for name in sorted(DEFLATERS, key=lambda n: n != DEFAULT_DEFLATER):
        try:
            if DEFLATERS[name].compress(rows) == stream:
                return name
        except ImportError:  # not installed here
            continue
    return None

