"""Offline replay: iterate a log source through the pipeline, faster than real time."""

from __future__ import annotations

import time
from collections.abc import Callable

from . import report

PROGRESS_EVERY = 4096  # frames between progress callbacks


def replay(source, pipeline, truth: dict | None = None, progress: Callable[[int, int], None] | None = None) -> dict:
    """Feed every frame of ``source`` to ``pipeline``; return the result document."""
    t0 = time.monotonic()
    first = last = None
    keep_ids = getattr(source, "keep_ids", None)
    if keep_ids is not None:  # lines of ids the profile does not decode never become Messages
        keep_ids(pipeline.decoder.ids)
    feed_into = getattr(source, "feed_into", None)
    if feed_into is not None:  # a bulk source (vdp.io.bulk) feeds the pipeline itself
        n, first = feed_into(pipeline, progress)
    else:
        feed = pipeline.feed
        n = 0
        for msg in source:
            feed(msg)
            n += 1
            if first is None:
                first = msg.timestamp
            if progress is not None and n % PROGRESS_EVERY == 0:
                progress(source.position, n)
    passed = getattr(source.stats, "passed_over", None)
    if passed:
        pipeline.pass_over(passed)
        n += sum(passed.values())
    if n:
        last = pipeline.last_bus_time if pipeline.last_bus_time is not None else first
    wall = time.monotonic() - t0
    result = pipeline.snapshot()
    duration = (last - first) if n and last is not None else 0.0
    # a log reader sums bus time over the runs between clock steps: never negative, never a jump's years
    bus_time = getattr(source.stats, "bus_time", None)
    if bus_time is not None:
        duration = bus_time
    log_info = {
        "path": str(getattr(source, "path", "")),
        "frames": n,
        "wall_s": wall,
        "duration_s": duration,
        "realtime_factor": duration / wall if wall > 0 else 0.0,
        "start_time": first,
    }
    log_info.update(source.stats.as_dict())
    log_info["decode"] = pipeline.decoder.stats.as_dict()
    log_info["clock"] = {"backwards": pipeline.aligner.clock_backwards, "jumps": pipeline.aligner.clock_jumps}
    result["log"] = log_info
    # windows relative to the log start, as the plot's time axis
    if first is not None:
        for w in result["windows"]:
            w["start"] -= first
            if w["end"] is not None:
                w["end"] -= first
        pipeline.estimator.trace = type(pipeline.estimator.trace)(
            (r[0] - first,) + tuple(r[1:]) for r in pipeline.estimator.trace
        )
    if truth is not None:
        result["truth"] = truth["parameters"]
        result["truth_comparison"] = report.compare(result["parameters"], truth)
        if result.get("baseline_ekf"):
            result["truth_comparison_ekf"] = report.compare(result["baseline_ekf"], truth)
    return result
