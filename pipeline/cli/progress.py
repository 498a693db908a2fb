"""What produce and verify tell the user while they run and when they stop: the
progress line with its moving-window rate, the signals that stop a run, and
the closing lines (interrupted, storage outage, the run's summary, verify's
advice). The commands are in ``pipeline.cli.app``."""

from __future__ import annotations

import contextlib

from pipeline.cli.common import count
from pipeline.status import format_duration

RATE_WINDOW = 20  # frames: the rate shown is over the last this many frames, "estimating" until there are that many


class RateWindow:
    """A moving-window rendering rate from successive progress counts.

    The run's average from the command's start mixes in Ray's start-up and the
    world builds, so early ETAs were far off. This rate counts from the first
    frame on, over the last ``size`` frames: ``rate`` is None ("estimating")
    until ``size`` frames have finished after the first one seen."""

    def __init__(self, size: int = RATE_WINDOW) -> None:
        from collections import deque

        self.size = size
        self._samples: deque[tuple[int, float]] = deque()  # (frames done, elapsed s) at each new count

    def add(self, frames_done: int, elapsed_s: float) -> None:
        if frames_done <= 0 or (self._samples and frames_done <= self._samples[-1][0]):
            return
        self._samples.append((frames_done, elapsed_s))
        while len(self._samples) > 2 and frames_done - self._samples[1][0] >= self.size:
            self._samples.popleft()

    @property
    def rate(self) -> float | None:
        """Frames per second over the window; None while estimating."""
        if len(self._samples) < 2:
            return None
        (f0, t0), (f1, t1) = self._samples[0], self._samples[-1]
        if f1 - f0 < self.size or t1 <= t0:
            return None
        return (f1 - f0) / (t1 - t0)


def format_progress(p, rate: float | None) -> str:
    """One progress line: frames, the window's rate and ETA ("estimating" without a rate), episodes."""
    share = 100 * p.frames_done / p.frames_total if p.frames_total else 100.0
    if rate is None:
        speed = "estimating rate and ETA"
    else:
        shown = f"{rate:,.2f}" if rate < 100 else f"{rate:,.0f}"
        speed = f"{shown} frame/s, ETA {format_duration((p.frames_total - p.frames_done) / rate)}"
    line = (
        f"rendering {p.frames_done:,}/{p.frames_total:,} frames ({share:.0f}%), {speed}, "
        f"episodes {p.episodes_done:,}/{p.episodes_total:,}, {format_duration(p.elapsed_s)} elapsed"
    )
    return line + (f", {p.failed} failed" if p.failed else "")


class ProgressDisplay:
    """Produce's progress on ``stream`` (stderr): on a terminal one line,
    redrawn at every progress report (at most one per task a second); otherwise
    (a log file, CI) one line per finished episode. The rate is a moving window (``RateWindow``)."""

    def __init__(self, stream=None, window: int = RATE_WINDOW) -> None:
        import sys

        self.stream = stream if stream is not None else sys.stderr
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.window = RateWindow(window)
        self._finished = 0
        self._width = 0

    def update(self, p) -> None:
        self.window.add(p.frames_done, p.elapsed_s)
        text = format_progress(p, self.window.rate)
        if self.tty:
            self.stream.write("\r" + text.ljust(self._width))
            self._width = len(text)
        elif p.episodes_done + p.failed > self._finished:
            self._finished = p.episodes_done + p.failed
            self.stream.write(text + "\n")
        else:
            return
        self.stream.flush()

    def close(self) -> None:
        if self.tty and self._width:
            self.stream.write("\n")
            self.stream.flush()
            self._width = 0


# Signals that stop a run as Ctrl-C does: a batch scheduler's SIGTERM, a closed terminal's SIGHUP.
STOP_SIGNALS = ("SIGTERM", "SIGHUP")


@contextlib.contextmanager
def stop_signals():
    """Turn STOP_SIGNALS into KeyboardInterrupt while the block runs, so a run stops
    as it does on Ctrl-C (leases released, Ray shut down). Yields a dict that
    receives the first signal's ``name`` (e.g. "stopped by SIGTERM") and exit ``code`` (128 + its number)."""
    import signal
    import threading

    stopped: dict = {}
    if threading.current_thread() is not threading.main_thread():
        yield stopped
        return

    def handler(signum, frame) -> None:
        if stopped:  # a second signal while stopping: the first one is being handled
            return
        stopped.update(name=f"stopped by {signal.Signals(signum).name}", code=128 + signum)
        raise KeyboardInterrupt

    chosen = [getattr(signal, name) for name in STOP_SIGNALS if hasattr(signal, name)]
    previous = {sig: signal.signal(sig, handler) for sig in chosen}
    try:
        yield stopped
    finally:
        for sig, old in previous.items():
            signal.signal(sig, old)


def format_interrupted(report, cause: str = "interrupted") -> str:
    """What an interrupted run did, and how to go on."""
    return (
        f"{cause}: {report.out} gained {count(report.rendered_frames, 'frame')} in "
        f"{count(report.rendered_episodes, 'episode')} this run; run the same command again to resume "
        "(finished episodes are kept, the rest render again)"
    )


def format_outage(outage, endpoint: str) -> str:
    """The one line of a run its storage stopped: the error, the endpoint, what is done, how to go on."""
    report = outage.report
    done = report.skipped_episodes + report.rendered_episodes
    message = " ".join(str(outage.error).split())
    return (
        f"error: {message} (storage: {endpoint}); {done:,} of {report.planned_episodes:,} episodes are done "
        f"({report.rendered_episodes:,} this run); run the same command again to resume once the storage answers"
    )


def format_head_lost(lost) -> str:
    """The one line of a run whose Ray head went away: what is committed, how to go on."""
    report = lost.report
    done = report.skipped_episodes + report.rendered_episodes
    return (f"error: {lost}; {done:,} of {report.planned_episodes:,} episodes committed "
            f"({report.rendered_episodes:,} this run); run the same command again to resume once the head is back")


def format_produce_report(report) -> str:
    lines = []
    if report.repaired:
        lines.append(f"repair: re-rendering {len(report.repaired)} damaged episode(s): {', '.join(report.repaired[:10])}"
                     + (" ..." if len(report.repaired) > 10 else ""))
    if report.reshifted:
        lines.append(f"extend: {count(len(report.reshifted), 'episode')} of a shifting weather made longer "
                     f"({', '.join(report.reshifted[:5])}{' ...' if len(report.reshifted) > 5 else ''}) rendered "
                     "again whole: a shift runs over its episode's length, so their earlier frames changed too")
    if report.per_scenario:
        w = max([10, *map(len, report.per_scenario)])  # a declared code may be longer than T01_HRN_A
        lines.append(f"{'scenario':<{w}} {'episodes':>8} {'frames':>8} {'worker s/frame':>15}")
        for code, row in sorted(report.per_scenario.items()):
            lines.append(f"{code:<{w}} {row['episodes']:>8} {row['frames']:>8} {row['seconds'] / max(row['frames'], 1):>15.2f}")
    if not report.rendered_episodes and not report.failed:
        lines.append(f"{report.out}: nothing to render; all {report.planned_episodes:,} planned episodes are done")
        return "\n".join(lines)
    rate = report.rendered_frames / report.seconds if report.seconds else 0.0
    workers = count(report.workers, "worker")
    if report.nodes_lost:  # what ran: the slots at the start, less the nodes lost on the way
        workers += f" at the start, {count(report.nodes_lost, 'node')} lost"
    lines.append(
        f"{report.out}: rendered {count(report.rendered_frames, 'frame')} in "
        f"{count(report.rendered_episodes, 'episode')} "
        f"({format_duration(report.seconds)}, {rate:.2f} frames/s on {workers}); "
        f"{report.skipped_episodes:,} of {report.planned_episodes:,} episodes were already done"
    )
    for key, error in report.failed:
        lines.append(f"FAILED {key}: {error}")
    if report.failed:
        lines.append(f"{len(report.failed)} episode(s) failed; run the same command again to retry them")
    return "\n".join(lines)


def verify_advice(report) -> str:
    """What to do about verify's findings: never a repair that would race a producer or follow a link."""
    links = [p.path for p in report.problems if p.kind == "link"]
    if links:
        return (f"{links[0]} is a symbolic link, which verify and repair never follow: replace it with the files "
                "it points to (or remove it), then run idda produce --repair (same options as the run)")
    if report.in_progress:
        return "A producer is writing into this root: when it has finished, run idda produce --repair (same options as the run)"
    return "Fix with: idda produce --repair (same options as the run)"


class VerifyDisplay:
    """Verify's progress on ``stream`` (stderr): a tqdm bar on a terminal,
    otherwise one line every ``every_s`` seconds (a log file, CI)."""

    def __init__(self, stream=None, every_s: float = 30.0) -> None:
        import sys

        self.stream = stream if stream is not None else sys.stderr
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self.every_s = every_s
        self._bar = None
        self._last_line, self._lines, self._final_written = 0.0, 0, False

    def update(self, p) -> None:
        if self.tty:
            if self._bar is None:
                from tqdm import tqdm

                self._bar = tqdm(total=p.episodes_total, unit="episode", desc="verify", file=self.stream, leave=False)
            self._bar.n = p.episodes_done
            self._bar.set_postfix_str(f"{p.files_done:,} files", refresh=False)
            self._bar.refresh()
        else:
            final = bool(p.episodes_total) and p.episodes_done == p.episodes_total
            due = p.elapsed_s - self._last_line >= self.every_s
            if not due and not (final and self._lines):  # a short run prints no progress at all
                return
            if final and self._final_written:
                return
            self._last_line, self._lines, self._final_written = p.elapsed_s, self._lines + 1, final
            self.stream.write(f"verify: {p.episodes_done:,}/{p.episodes_total:,} episodes, "
                              f"{p.files_done:,} files, {p.elapsed_s:.0f} s\n")
            self.stream.flush()

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None
