"""Synthetic manifest rows for a plan, without rendering anything.

Used by the manifest benchmark (a 1,006,800-row manifest) and by tests of the
query and stats code. The rows follow the real schema; pixel counts are drawn
around the paper's class shares, and checksums are fake (these files do not
exist, so never run ``verify`` on a synthetic root).
"""

from __future__ import annotations

import numpy as np

from manifests.catalog import LABELS, OUTPUTS, VIEWPOINT_BY_CODE
from manifests.schema import frame_id, frame_path, output_columns
from manifests.stats import PAPER_SHARES


def episode_rows(spec) -> list[dict]:
    """Plausible manifest rows for one planned episode (deterministic per spec)."""
    rng = np.random.default_rng([spec.seed % 2**32, spec.episode])
    shares = np.array([PAPER_SHARES[label.name] for label in LABELS])
    pixels = spec.width * spec.height
    n_vehicles = int(rng.integers(20, 151))
    n_pedestrians = int(rng.integers(0, 101))
    view = VIEWPOINT_BY_CODE[spec.viewpoint]
    rows = []
    for index in range(spec.frames):
        mix = rng.dirichlet(shares * 200 + 1e-3)
        counts = np.floor(mix * pixels).astype(np.int64)
        counts[20] += pixels - counts.sum()  # remainder to sky
        fid = frame_id(spec.episode, index)
        row = {
            "frame_id": fid,
            "scenario": spec.scenario,
            "episode": spec.episode,
            "frame": index,
            "sim_time_s": 3.0 * index,
            "split": spec.split,
            "seed": spec.seed,
            "n_vehicles": n_vehicles,
            "n_pedestrians": n_pedestrians,
            "camera_height_m": view.camera_height_m,
            "hood_fraction": view.hood_fraction,
            "ego_speed_mps": 10.0,
            "width": spec.width,
            "height": spec.height,
        }
        for output in OUTPUTS:
            path_col, bytes_col, sha_col = output_columns(output)
            row[path_col] = frame_path(spec.scenario, output, fid)
            row[bytes_col] = int(rng.integers(100_000, 3_000_000))
            row[sha_col] = f"{rng.integers(0, 2**63):016x}" * 4
        for label in LABELS:
            row[label.column] = int(counts[label.id])
        rows.append(row)
    return rows
