"""Deflaters side by side on real frames: ``python -m benchmarks.compare_deflaters ROOT``.

Takes the filtered rows out of the PNG files of ROOT's frames 10 and 40 of the first episode of
its first two scenarios (seven default PNG outputs each; ROOT e.g. the end-to-end run of
``BENCH=produce make bench``), deflates them with each candidate and prints the thread CPU
(median of 3 rounds) and bytes per frame, per output. Not part of ``make bench``: the figures
are in docs/bench_render.md ("Other deflaters").
"""

from __future__ import annotations

import statistics
import sys
import time
import zlib
from pathlib import Path

FRAMES = (10, 40)


def _png_outputs() -> tuple[str, ...]:
    """The default outputs written as PNG files (all but ``objects``), in table order."""
    from outputs.table import DEFAULT_OUTPUTS, FORMATS, output

    return tuple(name for name in DEFAULT_OUTPUTS if FORMATS[output(name).file].extension == "png")


OUTPUTS = _png_outputs()


def _zlib(level: int, strategy: int):
    def compress(data: bytes, output: str) -> bytes:
        c = zlib.compressobj(level, zlib.DEFLATED, 15, 8, strategy)
        return c.compress(data) + c.flush()
    return compress


def candidates() -> dict:
    """Name -> compress(data, output); the first is the deflater new roots use (``outputs.deflaters``), as
    they call it (a photograph's rows, ``outputs.encoding.PHOTO_OUTPUTS``, apart)."""
    import deflate
    from zlib_ng import zlib_ng

    from outputs.deflaters import DEFAULT_DEFLATER, deflater
    from outputs.encoding import PHOTO_OUTPUTS

    default, every_output_l3 = deflater(DEFAULT_DEFLATER), deflater("zlib-ng-l3")  # the eighth round's
    return {
        f"{default.name} {default.level}, rgb run-length": lambda d, o: default.deflate(d, o in PHOTO_OUTPUTS),
        "zlib-ng 3": lambda d, o: every_output_l3.compress(d),
        "zlib-ng 2": lambda d, o: zlib_ng.compress(d, 2),
        "zlib-ng 1": lambda d, o: zlib_ng.compress(d, 1),
        "zlib-ng rle": lambda d, o: default.photo(d),  # every output as a photograph
        "libdeflate 2": lambda d, o: bytes(deflate.zlib_compress(d, 2)),
        "libdeflate 1": lambda d, o: bytes(deflate.zlib_compress(d, 1)),
        "zlib 1": _zlib(1, zlib.Z_DEFAULT_STRATEGY),
        "zlib 1 rle": _zlib(1, zlib.Z_RLE),
        "zlib 6 rle": _zlib(6, zlib.Z_RLE),
        "zlib huffman": _zlib(1, zlib.Z_HUFFMAN_ONLY),
    }


def png_files(root: Path, indexes: tuple[int, ...] = FRAMES) -> list[dict[str, Path]]:
    """Output -> PNG file of frames ``indexes`` of episode 0 of ROOT's first two scenarios (a root in
    episode folders, the default layout), frame by frame."""
    from manifests.layout import EPISODE_DIRS, frame_path
    from manifests.schema import frame_id

    scenarios = sorted(p.name for p in root.iterdir() if p.is_dir() and not p.name.startswith("_"))[:2]
    return [{o: root / frame_path(scenario, o, frame_id(0, index), "png", EPISODE_DIRS) for o in OUTPUTS}
            for scenario in scenarios for index in indexes]


def frames(root: Path, indexes: tuple[int, ...] = FRAMES) -> list[dict[str, bytes]]:
    """The filtered rows of each of those PNG files (what their deflater was given)."""
    from outputs.deflaters import png_stream

    return [{o: zlib.decompress(png_stream(path.read_bytes())) for o, path in files.items()}
            for files in png_files(root, indexes)]


def measure(root: str, rounds: int = 3, indexes: tuple[int, ...] = FRAMES) -> dict[str, dict[str, tuple[float, float]]]:
    """Deflater -> output -> (median thread CPU seconds, mean bytes) per frame."""
    rows, codecs = frames(Path(root), indexes), candidates()
    cpu = {k: {o: [] for o in OUTPUTS} for k in codecs}
    size = {k: {o: 0 for o in OUTPUTS} for k in codecs}
    for r in range(rounds):
        for name, compress in codecs.items():
            for frame in rows:
                for o in OUTPUTS:
                    start = time.thread_time()
                    n = len(compress(frame[o], o))
                    cpu[name][o].append(time.thread_time() - start)
                    if r == 0:
                        size[name][o] += n
    return {k: {o: (statistics.median(cpu[k][o]), size[k][o] / len(rows)) for o in OUTPUTS} for k in codecs}


def table(figures: dict[str, dict[str, tuple[float, float]]]) -> str:
    """The figures as a Markdown table: ms and KB per output and per frame."""
    lines = ["| deflater | " + " | ".join(OUTPUTS) + " | per frame |", "|---|" + "---:|" * (len(OUTPUTS) + 1)]
    for name, row in figures.items():
        cells = [f"{row[o][0] * 1e3:.1f} ms, {row[o][1] / 1e3:.0f} KB" for o in OUTPUTS]
        cells.append(f"{sum(c for c, _ in row.values()) * 1e3:.1f} ms, {sum(b for _, b in row.values()) / 1e3:.0f} KB")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


if __name__ == "__main__":
    print(table(measure(sys.argv[1])))
