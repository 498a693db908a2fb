"""The paper's domain-shift table for docs/worlds.md (run by ``make report``).

Renders the paper's five domains (T01_CS_A, T01_CS_J, T01_HRN_J, T01_HRN_A,
T07_HRN_A; 150 frames each at 320x180, procedural world, run seed 0) into
``SHIFT_ROOT``, runs ``analysis.shift_table`` on them (the same as
``idda shifts SHIFT_ROOT``) and returns the table and the per-case figures.
:func:`markdown` turns them into the report's "Domain shift" section.

``.venv/bin/python -m reports.worlds_md shifts`` does only this part and
replaces the section in an existing docs/worlds.md (and ``shifts`` in
docs/worlds.json).
"""

from __future__ import annotations

import logging

from reports.sample import produce_sample

SHIFT_ROOT = "/tmp/idda-shifts-sample"  # outside git; rebuilt on every run
SHIFT_DOMAINS = "T01_CS_A,T01_CS_J,T01_HRN_J,T01_HRN_A,T07_HRN_A"
FRAMES, WIDTH, HEIGHT = 150, 320, 180
TOLERANCE = 0.15  # kept fractions should be within this of the paper's
SECTION_TITLE = "## Domain shift: the paper's table with a small network"

log = logging.getLogger(__name__)


def measure(root: str = SHIFT_ROOT, frames: int = FRAMES, width: int = WIDTH, height: int = HEIGHT,
            workers: int = 2) -> dict:
    """Render the five domains and run the shift table on them; an error dict if torch is missing."""
    try:
        from analysis.shift_table import ShiftConfig, format_shift_table, require_torch, run_shifts

        require_torch()
    except ImportError as exc:
        return {"error": str(exc)}
    log.info("rendering the five shift domains into %s (%d frames each, %dx%d)", root, frames, width, height)
    sample = produce_sample(root, frames, width, height, workers, SHIFT_DOMAINS)
    log.info("training the shift table's networks")
    report = run_shifts(ShiftConfig(root=root))
    result = report.to_json()
    result.update(table=format_shift_table(report), sample=dict(sample, frames_per_scenario=frames, width=width,
                                                                 height=height, root=root))
    return result


def _verdict(results: list[dict]) -> list[str]:
    paper = [r["case"] for r in sorted(results, key=lambda r: -r["paper_kept"])]
    lines = []
    for label, key in (("kept (of held-out source mIoU)", "kept"), ("kept* (of the target oracle's mIoU, the paper's definition)", "oracle_kept")):
        ordered = [r["case"] for r in sorted(results, key=lambda r: -r[key])]
        lines += [f"{label[0].upper()}{label[1:]}: order {' > '.join(ordered)} "
                  f"({'as in' if ordered == paper else 'not as in'} the paper: {' > '.join(paper)}).", ""]
        for r in results:
            ok = abs(r[key] - r["paper_kept"]) <= TOLERANCE
            lines.append(f"* {r['case']}: {r[key]:.2f} against the paper's {r['paper_kept']:.2f}: "
                         f"{'within' if ok else '**not** within'} {TOLERANCE} of it.")
        lines.append("")
    return lines


def markdown(result: dict) -> list[str]:
    """The report's "Domain shift" section."""
    lines = ["", SECTION_TITLE, ""]
    if "error" in result:
        return lines + [f"Not computed: {result['error']}", ""]
    s, cfg = result["sample"], result["config"]
    lines += [
        f"`idda shifts` (analysis/shift_table.py) on the paper's five domains, {s['frames_per_scenario']} frames each at "
        f"{s['width']}x{s['height']} (procedural world, run seed 0). For each case a small encoder-decoder "
        f"({result['parameters']:,} parameters, trained from scratch at {cfg['width']}x{cfg['height']}, "
        f"{cfg['steps']} steps of {cfg['batch_size']} frames) learns the source domain and is scored on the "
        "source's held-out frames and on the target. *kept* = target mIoU / held-out source mIoU. *kept\\** is "
        "the paper's definition: the source network on the target's held-out frames (*target\\**) over an "
        "*oracle*, the same network trained on the target's training frames, on those held-out frames; the "
        "paper's is DeepLab V2 source-only / trained on the target (62.60/79.13, 40.24/78.31, 21.65/78.02). "
        "One network is trained per domain, so the weather case's source network (T01_CS_J) is the viewpoint "
        "case's oracle. mIoU over the 16 evaluated classes present in the ground truth of the scored set.",
        "",
        "```",
        result["table"],
        "```",
        "",
    ]
    lines += _verdict(result["results"])
    lines += ["Reproduce: `idda produce --domains " + SHIFT_DOMAINS + f" --frames-per-scenario {s['frames_per_scenario']} "
              f"--width {s['width']} --height {s['height']} --out {s['root']}` then `idda shifts {s['root']}`.", ""]
    return lines
