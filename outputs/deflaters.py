"""The deflate inside every PNG file this tool writes, and which one a root keeps.

New roots deflate with zlib-ng (the ``zlib-ng`` package bundles it) at
:data:`ZLIBNG_LEVEL`, and a photograph (the ``rgb`` output,
``outputs.encoding.PHOTO_OUTPUTS``) with run-length matches only (``Z_RLE``):
after the Sub filter a rendered, post-processed frame holds few repeats but
runs, so level 3's full match search made its file 1.7% smaller for 35% more
CPU (751 against 764 KB, 23.4 against 15.3 ms per full-HD frame).

One frame is one sequence of bytes however often, wherever and in whichever
process it is rendered, for one version of the package, because nothing but
the input chooses a match: zlib-ng (2.2 on) hashes
with one function on every CPU (the SSE4.2 and ARM CRC-32 hashes were removed),
the functions it picks by CPU for deflate (``compare256``, ``longest_match``,
``slide_hash``, ``adler32``) return the same values on every path, only faster,
and it zeroes its hash tables and the window bytes past the data before the
match search can read them (docs/contract.md: checked against a build with no
CPU-specific code at all). Issue 35: at level 3 its PNGs are as small as
libdeflate's level 2 (1,271 against 1,266 KB per full-HD frame) for 46 against
84 CPU-ms: libdeflate spends ~10 ms on each low-entropy output (depth grey and
log, the two semantic images), zlib-ng ~2.

Roots written before keep their deflater (their ``run.json`` names it, see
``outputs.encoding.encoder_identity``): zlib-ng level 3 for every output
(issue 35's eighth round), libdeflate level 2 (issue 21.11 to 35) or ISA-L
level 1 (before). ISA-L is fast but gave two different byte streams for the
same input in two worker processes (issue 21.11: same pixels, same
filtered rows, one match found in one process and not in the other), which
breaks resume and verify, since a re-rendered frame must equal its files; so
resuming, extending and repairing an old root mix nothing. The deflater in force
is a context variable, set per frame around the encoding (:func:`deflating_with`),
so two threads may encode for two roots at once.
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass
from functools import cache

from domains.catalog import lookup

ZLIBNG_LEVEL = 3  # zlib-ng 1..9: level 3 (deflate_medium) is as small as libdeflate's 2 at ~half its CPU; 2 is 9% larger
LIBDEFLATE_LEVEL = 2  # what roots written with libdeflate (issue 21.11 to 35) use
ISAL_LEVEL = 1  # what roots written with ISA-L used


def _zlib_ng(data) -> bytes:
    from zlib_ng import zlib_ng

    return zlib_ng.compress(data, ZLIBNG_LEVEL)


def _zlib_ng_runs(data) -> bytes:
    """zlib-ng with run-length matches only (``Z_RLE``; the level then chooses nothing), one call. A match
    repeats the byte before it, its length the equal bytes that follow, clamped to the data: no hash, no
    window search, so the stream follows from the input alone as level 3's does."""
    from zlib_ng import zlib_ng

    c = zlib_ng.compressobj(ZLIBNG_LEVEL, zlib_ng.DEFLATED, 15, 8, zlib_ng.Z_RLE)
    return c.compress(data) + c.flush()


def _libdeflate(data) -> bytes:
    import deflate

    return bytes(deflate.zlib_compress(data, LIBDEFLATE_LEVEL))


def _isal(data) -> bytes:
    from isal import isal_zlib

    return isal_zlib.compress(data, ISAL_LEVEL)


@dataclass(frozen=True)
class Deflater:
    """One deflate implementation: its name in run records, its level, the package that provides it."""

    name: str  # its key in DEFLATERS
    level: int
    package: str
    compress: Callable[[bytes], bytes]  # data -> a zlib stream (RFC 1950)
    photo: Callable[[bytes], bytes] | None = None  # a photograph's rows (outputs.encoding.PHOTO_OUTPUTS); None: compress
    family: str = ""  # the deflater's name in the identity, where the key says more (default: the key)

    def deflate(self, data, photo: bool = False) -> bytes:
        """The zlib stream of a PNG's filtered rows; ``photo``: the rows of a photograph."""
        return (self.photo if photo and self.photo is not None else self.compress)(data)

    @property
    def identity(self) -> str:
        """How run.json names PNG files deflated by this (the package version included:
        another version may give other bytes)."""
        from importlib import metadata

        photos = ", rgb run-length" if self.photo is not None else ""
        return (f"png-sub-{self.family or self.name} level {self.level}{photos}, "
                f"{self.package} {metadata.version(self.package)}")


DEFLATERS = {
    "zlib-ng": Deflater("zlib-ng", ZLIBNG_LEVEL, "zlib-ng", _zlib_ng, photo=_zlib_ng_runs),
    # roots of issue 35's eighth round: level 3 for every output, photographs too
    "zlib-ng-l3": Deflater("zlib-ng-l3", ZLIBNG_LEVEL, "zlib-ng", _zlib_ng, family="zlib-ng"),
    "libdeflate": Deflater("libdeflate", LIBDEFLATE_LEVEL, "deflate", _libdeflate),  # roots of issues 21.11-35
    "isal": Deflater("isal", ISAL_LEVEL, "isal", _isal),  # roots written before libdeflate
}
DEFAULT_DEFLATER = "zlib-ng"
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


def deflate_png_data(data, photo: bool = False) -> bytes:
    """The zlib stream of a PNG's filtered rows, by the deflater in force; ``photo``: a photograph's rows."""
    return deflater().deflate(data, photo)


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


def deflaters_of_png(png: bytes, photo: bool = False) -> set[str]:
    """The installed deflaters that give this PNG's zlib stream from its own rows (``photo``: the file
    of a photograph); none for a damaged file or another deflater's. Several may: zlib-ng's two give
    every file but a photograph the same bytes."""
    import zlib

    stream = png_stream(png)
    try:
        rows = zlib.decompress(stream)
    except zlib.error:
        return set()
    found = set()
    for name, row in DEFLATERS.items():
        try:
            if row.deflate(rows, photo) == stream:
                found.add(name)
        except ImportError:  # not installed here
            continue
    return found


def deflater_of_files(found: list[set[str]]) -> str | None:
    """The one deflater that gives every file of ``found`` (each file's ``deflaters_of_png``; a file none
    gives, damaged, says nothing): the default where it does, else the only one; None where none or
    several do."""
    found = [names for names in found if names]
    common = set.intersection(*found) if found else set()
    if DEFAULT_DEFLATER in common:
        return DEFAULT_DEFLATER
    return common.pop() if len(common) == 1 else None

