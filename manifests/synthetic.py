"""Synthetic manifest parts for a plan, without rendering anything.

Used by the manifest benchmark (a 1,006,800-row manifest) and by tests of the
query and stats code. Parts follow the real schema; pixel counts are drawn
around the paper's class shares, and checksums are fake (these files do not
exist, so never run ``verify`` on a synthetic root).
"""

from __future__ import annotations

import numpy as np
import pyarrow as pa

from domains.catalog import INSTANCE_LABELS, LABELS, using, viewpoint, weather
from domains.conditions import FOG_DENSITY, VISIBILITY, frame_conditions
from domains.ramps import weather_at
from manifests.writer import write_part
from outputs.geometry import HFOV_DEG, flat, intrinsics
from outputs.table import CAMERA_OUTPUTS
from manifests.layout import frame_path
from manifests.schema import OLD_PART_SCHEMA, RULE_PART_SCHEMA, frame_id, output_columns
from manifests.schema import NEW_RULES
from manifests.stats import PAPER_SHARES

_SHARES = np.array([PAPER_SHARES[label.name] for label in LABELS])


def episode_table(spec) -> pa.Table:
    """A plausible manifest part for one planned episode (deterministic per spec)."""
    rng = np.random.default_rng([spec.seed % 2**32, spec.episode])
    n = spec.frames
    pixels = spec.width * spec.height
    with using(spec.catalog):
        view = viewpoint(spec.viewpoint)
        row = weather(spec.weather)
        conditions = [frame_conditions(weather_at(row, i, n, weather, spec.rules < NEW_RULES)) for i in range(n)]
    counts = np.floor(rng.dirichlet(_SHARES * 200 + 1e-3, size=n) * pixels).astype(np.int64)
    counts[:, 20] += pixels - counts.sum(axis=1)  # remainder to sky
    fids = [frame_id(spec.episode, i) for i in range(n)]
    columns = {
        "frame_id": fids,
        "uid": [f"{f}_{spec.scenario}" for f in fids],
        "scenario": [spec.scenario] * n,
        "episode": np.full(n, spec.episode, np.int32),
        "frame": np.arange(n, dtype=np.int32),
        "sim_time_s": (spec.frame_interval_s * np.arange(n)).astype(np.float32),
        "split": [spec.split] * n,
        "seed": np.full(n, spec.seed, np.int64),
        "n_vehicles": np.full(n, rng.integers(20, 151), np.int16),
        "n_pedestrians": np.full(n, rng.integers(0, 101), np.int16),
        "camera_height_m": np.full(n, view.camera_height_m, np.float32),
        "hood_fraction": np.full(n, view.hood_fraction, np.float32),
        "ego_speed_mps": np.full(n, 10.0, np.float32),
        "width": np.full(n, spec.width, np.int32),
        "height": np.full(n, spec.height, np.int32),
    }
    columns.update(_poses(spec, view.camera_height_m, spec.frame_interval_s * np.arange(n)))
    columns.update({name: np.array([c[name] for c in conditions], np.float32) for name in conditions[0]})
    if spec.rules < NEW_RULES:  # a root made before rules: no visibility_m (manifests.writer.frame_row)
        del columns[VISIBILITY.column]
    else:
        columns[VISIBILITY.column] = np.array([c[VISIBILITY.column] for c in conditions], np.float64)
        columns[FOG_DENSITY.column] = pa.nulls(n, pa.float32())
    for output in CAMERA_OUTPUTS:
        path_col, bytes_col, sha_col = output_columns(output)
        columns[path_col] = [frame_path(spec.scenario, output, f, spec.rgb_format, spec.layout) for f in fids]
        columns[bytes_col] = rng.integers(100_000, 3_000_000, n)
        columns[sha_col] = [bytes(row).hex() for row in rng.integers(0, 256, (n, 32), dtype=np.uint8)]
    for label in LABELS:
        columns[label.column] = counts[:, label.id]
    for label in INSTANCE_LABELS:
        columns[label.object_column] = rng.integers(0, 20, n, dtype=np.int32)
    return pa.table(columns, schema=RULE_PART_SCHEMA if spec.rules >= NEW_RULES else OLD_PART_SCHEMA)


def _poses(spec, camera_height_m: float, times: np.ndarray) -> dict[str, list]:
    """Calibration and poses of an ego driving along world +x at 10 m/s (outputs.geometry's convention)."""
    cam_to_ego = np.array([[0.0, 0.0, 1.0, 0.2], [-1.0, 0.0, 0.0, 0.0], [0.0, -1.0, 0.0, camera_height_m],
                           [0.0, 0.0, 0.0, 1.0]])
    ego = [np.eye(4) for _ in times]
    for pose, t in zip(ego, times):
        pose[0, 3] = 10.0 * t
    K = flat(intrinsics(spec.width, spec.height, HFOV_DEG))
    return {"K": [K] * len(times), "cam_to_world": [flat(e @ cam_to_ego) for e in ego],
            "ego_to_world": [flat(e) for e in ego], "cam_to_ego": [flat(cam_to_ego)] * len(times)}


def episode_rows(spec) -> list[dict]:
    """The same part as a list of row dicts (the writer's input form)."""
    return episode_table(spec).to_pylist()


def write_parts(storage, specs, threads: int = 16) -> int:
    """Write a synthetic part per episode spec through the real manifest writer
    (no frame files); returns how many."""
    from concurrent.futures import ThreadPoolExecutor


    with ThreadPoolExecutor(max_workers=threads) as pool:  # many PUTs at once on S3
        list(pool.map(lambda spec: write_part(storage, spec.scenario, spec.episode, episode_table(spec)), specs))
    return len(specs)
