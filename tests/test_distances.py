"""Domain distances: the math on hand-computed values, the pipeline against an
independent numpy computation, the feature extractor, and the command."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from PIL import Image
from typer.testing import CliRunner

from analysis import distances as d
from tests.test_export import cli_app, make_tiny_root


def test_euclidean_and_cosine_by_hand():
    assert d.euclidean_distance([0, 0], [3, 4]) == 5.0
    assert d.cosine_distance([1, 0], [0, 1]) == pytest.approx(1.0)
    assert d.cosine_distance([1, 0], [-2, 0]) == pytest.approx(2.0)
    assert d.cosine_distance([1, 1], [2, 2]) == pytest.approx(0.0)
    assert d.cosine_distance([1, 0], [1, 1]) == pytest.approx(1 - 1 / math.sqrt(2))
    with pytest.raises(ValueError, match="zero vector"):
        d.cosine_distance([0, 0], [1, 0])


def test_bhattacharyya_by_hand():
    # Same Gaussian: 0. Means 0 and 2, unit variances: 1/4 * 4 / 2 = 0.5.
    # Equal means, variances 1 and 4: 1/4 ln(1/4 (1/4 + 4 + 2)) = 1/4 ln(25/16).
    got = d.bhattacharyya_gaussian([0, 0, 5], [1, 1, 1], [0, 2, 5], [1, 1, 4])
    assert got == pytest.approx([0.0, 0.5, 0.25 * math.log(25 / 16)])
    # Samples: a = {(0,0), (2,2)} -> mean (1,1), var (1,1); b = {(1,3), (3,5)} -> mean (2,4), var (1,1).
    # Per feature 1/4 (dm^2)/2: 1/8 and 9/8; averaged: 5/8.
    a = np.array([[0.0, 0.0], [2.0, 2.0]])
    b = np.array([[1.0, 3.0], [3.0, 5.0]])
    assert d.bhattacharyya_distance(a, b) == pytest.approx(5 / 8)
    assert d.bhattacharyya_distance(a, a) == 0.0
    with pytest.raises(ValueError, match="2 and 3 features"):
        d.bhattacharyya_distance(a, np.zeros((2, 3)))


def test_pca_matches_covariance_eigenvectors():
    rng = np.random.default_rng(0)
    x = rng.normal(size=(40, 5)) @ rng.normal(size=(5, 5))
    pca = d.fit_pca(x, 3)
    values, vectors = np.linalg.eigh(np.cov(x, rowvar=False))
    order = np.argsort(values)[::-1][:3]
    assert pca.explained_variance == pytest.approx(values[order])
    for comp, vec in zip(pca.components, vectors[:, order].T):
        assert abs(np.dot(comp, vec)) == pytest.approx(1.0)
        assert comp[np.abs(comp).argmax()] > 0  # sign convention
    assert pca.transform(x).mean(0) == pytest.approx(np.zeros(3), abs=1e-9)
    assert len(d.fit_pca(x[:4], 50).components) == 4  # capped by the rows


def test_compare_domains_matches_plain_numpy():
    rng = np.random.default_rng(1)
    codes = ["T01_CS_A", "T01_CS_J", "T01_HRN_J", "T01_HRN_A", "T07_HRN_A", "T02_CN_B"]
    features = {c: rng.normal(loc=i, scale=1 + 0.3 * i, size=(12, 8)) for i, c in enumerate(codes)}
    features["T02_CN_B"] = features["T02_CN_B"][:7]
    report = d.compare_domains(features, pairs=(("T02_CN_B", "T01_CS_A"),), components=5)

    # Independent route: z-score, eigen-decompose the covariance, project.
    stacked = np.concatenate([features[c] for c in sorted(codes)])
    z = (stacked - stacked.mean(0)) / stacked.std(0)
    values, vectors = np.linalg.eigh(np.cov(z, rowvar=False))
    proj = z @ vectors[:, np.argsort(values)[::-1][:5]]
    sizes = [len(features[c]) for c in sorted(codes)]
    parts = dict(zip(sorted(codes), np.split(proj, np.cumsum(sizes)[:-1])))

    def by_hand(s, t):
        ms, mt = parts[s].mean(0), parts[t].mean(0)
        vs, vt = parts[s].var(0), parts[t].var(0)
        bhat = np.mean(0.25 * np.log(0.25 * (vs / vt + vt / vs + 2)) + 0.25 * (ms - mt) ** 2 / (vs + vt))
        cos = 1 - ms @ mt / (np.linalg.norm(ms) * np.linalg.norm(mt))
        return np.linalg.norm(ms - mt), cos, bhat

    assert [(r.case, r.source, r.target) for r in report.pairs] == [
        ("viewpoint", "T01_CS_A", "T01_CS_J"), ("weather", "T01_CS_J", "T01_HRN_J"),
        ("city", "T01_HRN_A", "T07_HRN_A"), ("", "T02_CN_B", "T01_CS_A"),
    ]
    for row in report.pairs:
        assert (row.euclidean, row.cosine, row.bhattacharyya) == pytest.approx(by_hand(row.source, row.target))
    assert report.components == 5 and report.samples["T02_CN_B"] == 7
    assert report.embedding.shape == (6, 2)
    assert report.pairs[0].paper.euclidean == 2.7604


def test_missing_domains():
    rng = np.random.default_rng(2)
    features = {"T01_CS_A": rng.normal(size=(4, 3)), "T01_CS_J": rng.normal(size=(4, 3))}
    report = d.compare_domains(features)
    assert report.pairs[0].euclidean is not None
    assert report.pairs[1].missing == ("T01_HRN_J",) and report.pairs[1].euclidean is None
    assert "not produced: T01_HRN_J" in d.format_distance_table(report)
    with pytest.raises(ValueError, match="no frames for T05_CN_B; domains with frames: T01_CS_A, T01_CS_J"):
        d.compare_domains(features, pairs=(("T01_CS_A", "T05_CN_B"),))


@pytest.mark.parametrize("n", [2, 3])
def test_no_cosine_distance_where_centred_means_fix_it(n):
    """Issue 32: over 2 domains the centred means are opposite (cosine distance always 2), over 3 they
    close a triangle: the table gives no value and says why in one line; from 4 domains it gives one."""
    rng = np.random.default_rng(5)
    codes = ["T01_CS_A", "T01_CS_J", "T01_HRN_J", "T07_HRN_A"]
    features = {code: rng.normal(i, 1.0, size=(6, 4)) for i, code in enumerate(codes)}
    few = d.compare_domains({c: features[c] for c in codes[:n]}, components=3)
    assert [r.cosine for r in few.pairs if not r.missing] == [None] * (n - 1)
    assert all(r.euclidean is not None for r in few.pairs if not r.missing)
    table = d.format_distance_table(few)
    assert table.splitlines()[2].split()[5] == "-" and "2.0000" not in table
    assert table.splitlines()[-1].startswith(f"cosine: not given: the means of {n} domains")
    four = d.compare_domains(features, components=3)
    assert all(r.cosine is not None for r in four.pairs if not r.missing)
    assert "cosine: not given" not in d.format_distance_table(four)


def test_distance_table_aligns_long_codes():
    rng = np.random.default_rng(6)
    codes = ["T01_CS_A", "T01_CS_J", "TownWithALongName_CNtoNT_B2", "T07_HRN_A"]
    features = {code: rng.normal(i, 1.0, size=(5, 4)) for i, code in enumerate(codes)}
    report = d.compare_domains(features, pairs=((codes[2], codes[0]),), components=3)
    table = d.format_distance_table(report)
    lines = table.splitlines()
    rows = [lines[0]] + lines[2:2 + len(report.pairs)]
    assert len(rows) == 5 and codes[2] in rows[-1]
    # where each column starts (case, source, target: left-aligned) or ends (the numbers: right-aligned)
    edges = [[m.start() if i < 3 else m.end() for i, m in enumerate(re.finditer(r"\S+", row))][:9] for row in rows]
    assert all(e == edges[0] for e in edges), table


def test_parse_pairs():
    assert d.parse_pairs("T01_CS_A:T01_CS_J, T02_CN_B:T03_HRN_M") == (("T01_CS_A", "T01_CS_J"), ("T02_CN_B", "T03_HRN_M"))
    with pytest.raises(ValueError, match="SOURCE:TARGET"):
        d.parse_pairs("T01_CS_A")
    with pytest.raises(ValueError, match="unknown town 'T09'"):
        d.parse_pairs("T09_CS_A:T01_CS_A")


def test_filter_bank_is_fixed_and_sensitive():
    rng = np.random.default_rng(3)
    image = rng.integers(0, 256, size=(36, 64, 3), dtype=np.uint8)
    a, b = d.FilterBank(0), d.FilterBank(0)
    assert a(image).shape == (a.size,) and np.array_equal(a(image), b(image))
    assert not np.array_equal(a(image), d.FilterBank(1)(image))
    darker = (image * 0.5).astype(np.uint8)
    assert not np.allclose(a(image), a(darker))
    with pytest.raises(ValueError, match="HxWx3 uint8"):
        a(image[..., 0])


def test_distances_command_end_to_end(tmp_path_factory, tmp_path):
    root = make_tiny_root(tmp_path_factory)
    plot = tmp_path / "domains.png"
    result = CliRunner().invoke(
        cli_app(), ["distances", str(root), "--samples", "2", "--chart", str(plot), "--pairs", "T01_CS_A:T07_HRN_A"]
    )
    assert result.exit_code == 0, result.output
    lines = result.output.splitlines()
    assert lines[2].split()[:3] == ["viewpoint", "T01_CS_A", "T01_CS_J"] and "2.7604" in lines[2]
    assert lines[5].split()[:3] == ["-", "T01_CS_A", "T07_HRN_A"]
    assert "5 domains, 2 frames each, PCA to 10 components" in result.output
    assert Image.open(plot).size[0] > 100
    # The table is reproducible: same root, same numbers.
    again = CliRunner().invoke(cli_app(), ["distances", str(root), "--samples", "2"])
    assert again.output.splitlines()[2:5] == lines[2:5]
    bad = CliRunner().invoke(cli_app(), ["distances", str(root), "--pairs", "T01_CS_A:T04_CN_M"])
    assert bad.exit_code == 2 and "no frames for T04_CN_M" in bad.output
