"""One full-HD frame in production's loop, by thread and stage: wall and CPU seconds.

``python -m benchmarks.profile_frame`` (``PF_FRAMES``, default 8; ``PF_SCENARIO``, default
T01_CN_A): after a 2-frame warm-up, one episode through ``render_episode`` with a sink that
encodes and writes every default output as ``pipeline.episode_job.store_frame`` does, output
by output. Each stage is timed where it runs: wall (``perf_counter``) and the CPU of its
own thread (``thread_time``); llvmpipe's rasteriser threads are read from /proc. Prints JSON,
seconds per frame. The numbers are a profile, not a benchmark: the wrappers cost a little,
and wall times move with the machine's load (CPU per thread moves less).
"""

from __future__ import annotations

import json
import os
import tempfile
import time
from collections import defaultdict
from pathlib import Path

FRAMES = int(os.environ.get("PF_FRAMES", 8))
SCENARIO = os.environ.get("PF_SCENARIO", "T01_CN_A")
WIDTH, HEIGHT = 1920, 1080


def _threads_cpu() -> dict[tuple[str, str], float]:
    """CPU seconds of each live thread of this process, by (tid, name)."""
    out = {}
    for tid in os.listdir("/proc/self/task"):
        try:
            with open(f"/proc/self/task/{tid}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
            with open(f"/proc/self/task/{tid}/comm") as f:
                name = f.read().strip()
        except OSError:  # gone meanwhile
            continue
        out[(tid, name)] = (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    return out


def main() -> dict:
    import outputs.encoding as enc
    import manifests.writer as writer
    import render_workers.render.episode as ep
    import render_workers.render.renderer as rr
    from outputs.deflaters import deflating_with
    from outputs.table import file_bytes, output
    from roots.episode_spec import EpisodeSpec
    from render_workers.render import postfx

    spent = defaultdict(lambda: [0.0, 0.0])  # stage -> [wall, CPU of its thread]

    def timed(name, fn):
        def wrapper(*args, **kwargs):
            wall, cpu = time.perf_counter(), time.thread_time()
            try:
                return fn(*args, **kwargs)
            finally:
                spent[name][0] += time.perf_counter() - wall
                spent[name][1] += time.thread_time() - cpu
        return wrapper

    rr.Renderer.render = timed("render thread: GL passes (Python side)", rr.Renderer.render)
    rr.RenderResult._resolve = timed("second thread: resolve", rr.RenderResult._resolve)
    postfx.apply = timed("second thread: post_fx", postfx.apply)
    ep.frame_objects = timed("second thread: objects table", ep.frame_objects)
    ep.object_counts = timed("second thread: object counts", ep.object_counts)
    ep.finish_frame = timed("second thread: finish_frame (resolve, post_fx, outputs)", ep.finish_frame)
    enc.deflate_png_data = timed("second thread: sink: PNG deflate (the default deflater)", enc.deflate_png_data)
    enc._sub_filtered = timed("second thread: sink: PNG Sub filter", enc._sub_filtered)
    writer.sha256_bytes = timed("second thread: sink: sha256", writer.sha256_bytes)

    written: dict[str, int] = defaultdict(int)
    with rr.Renderer() as renderer, tempfile.TemporaryDirectory() as tmp:
        def episode(frames: int) -> tuple:
            spec = EpisodeSpec(SCENARIO, 0, 1, frames, WIDTH, HEIGHT, "train", 0)

            def sink(frame) -> None:  # store_frame's work, output by output
                files = {}
                with deflating_with(spec.png_deflater):
                    for name in spec.outputs:
                        row = output(name)
                        content = timed(f"second thread: sink: array {name}", row.encode)(frame.buffers[row.source])
                        files[name] = file_bytes(name, content, spec.rgb_format)
                for name, data in files.items():
                    timed("second thread: sink: write", (Path(tmp) / f"{frame.index}_{name}").write_bytes)(data)
                    written[name] += len(data)
                timed("second thread: sink: manifest row", writer.frame_row)(spec, frame, files)

            before, cpu, wall = _threads_cpu(), time.process_time(), time.perf_counter()
            info = ep.render_episode(spec.drawing, timed("second thread: sink (all)", sink), renderer=renderer)
            return info, time.perf_counter() - wall, time.process_time() - cpu, before, _threads_cpu()

        episode(2)  # warm-up: shaders, uploads, caches
        spent.clear()
        written.clear()
        info, wall, cpu, before, after = episode(FRAMES)
    gl_threads = defaultdict(float)
    for key, seconds in after.items():
        if key[1].startswith("llvmpipe"):
            gl_threads[key[1]] += seconds - before.get(key, 0.0)
    return {
        "scenario": SCENARIO, "frames": FRAMES, "load_average": os.getloadavg(),
        "frame_wall_s": wall / FRAMES, "process_cpu_s": cpu / FRAMES,
        "episode_stages_wall_s": {k: v / FRAMES for k, v in info.timings.items()},
        "stages": {k: {"wall_s": w / FRAMES, "cpu_s": c / FRAMES} for k, (w, c) in sorted(spent.items())},
        "llvmpipe_threads_cpu_s": {k: v / FRAMES for k, v in sorted(gl_threads.items())},
        "bytes": {k: v // FRAMES for k, v in written.items()},
    }


if __name__ == "__main__":
    print(json.dumps(main(), indent=1))
