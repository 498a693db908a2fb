"""`python -m benchmarks.compare_deflaters ROOT` on a tiny real root: the rows it takes out of the PNG
files are the ones their streams were deflated from, and its table says every candidate."""

from __future__ import annotations

from benchmarks import compare_deflaters as bench


def test_the_default_deflater_gives_back_each_files_own_stream(reference):
    from outputs.deflaters import png_stream

    figures = bench.measure(str(reference), rounds=1, indexes=(0, 3))
    assert list(figures) == list(bench.candidates())
    files = bench.png_files(reference, (0, 3))
    assert len(files) == 4 and all(path.is_file() for frame in files for path in frame.values())
    for output in bench.OUTPUTS:
        streams = [len(png_stream(frame[output].read_bytes())) for frame in files]
        # the root was written with the default deflater: its rows, deflated again, are its streams byte for byte
        assert figures[next(iter(figures))][output][1] == sum(streams) / len(streams)
        assert all(cpu >= 0 and size > 0 for cpu, size in (row[output] for row in figures.values()))
    page = bench.table(figures)
    assert page.count("\n") == len(figures) + 1 and "| zlib 1 rle |" in page
