"""`python -m benchmarks.compare_deflaters ROOT` on a tiny real root: the rows it takes out of the PNG
files are the ones their streams were deflated from, and its table says every candidate."""

from __future__ import annotations

from benchmarks import compare_deflaters as bench


def test_the_default_deflater_gives_back_each_files_own_stream(reference):
    from outputs.deflaters import png_stream

    figures = bench.measure(str(reference), rounds=1, indexes=(0, 3))
    assert list(figures) == list(bench.candidates())
    scenarios = sorted(p for p in reference.iterdir() if p.is_dir() and not p.name.startswith("_"))[:2]
    for output in bench.OUTPUTS:
        streams = [len(png_stream(next((s / "e0000" / output).glob(f"0000_{i:03d}_*.png")).read_bytes()))
                   for s in scenarios for i in (0, 3)]
        # the root was written with libdeflate level 2: its rows, deflated again, are its streams byte for byte
        assert figures["libdeflate 2"][output][1] == sum(streams) / len(streams)
        assert all(cpu >= 0 and size > 0 for cpu, size in (row[output] for row in figures.values()))
    page = bench.table(figures)
    assert page.count("\n") == len(figures) + 1 and "| zlib 1 rle |" in page
