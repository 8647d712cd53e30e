"""The bulk candump reader gives the per-frame path's result to the last bit."""

import gzip
import json
import logging

import pytest

from vdp.core.estimator import EstimatorConfig
from vdp.io import bulk
from vdp.io.bulk import BulkSource, Irregular
from vdp.pipeline import Pipeline
from vdp.profile import load_profile
from vdp.replay import replay_log
from vdp.sim.run import simulate, write_log


def both(path, profile, **kw):
    """(per-frame, bulk) documents and pipelines, wall times left out."""
    out = []
    for is_bulk in (False, True):
        doc, pipe = replay_log(
            path, lambda: Pipeline(profile, EstimatorConfig(baseline=False)), bulk=is_bulk,
            channel=profile.bus_channel, **kw,
        )  # fmt: skip
        doc = json.loads(json.dumps(doc.to_dict()))
        for k in ("wall_s", "realtime_factor"):
            doc["log"].pop(k)
        out.append((doc, pipe))
    return out


@pytest.fixture(scope="module")
def paper(repo_root):
    return load_profile(repo_root / "profiles" / "paper.toml")


@pytest.fixture(scope="module")
def mixed(tmp_path_factory, paper):
    """30 s of the paper drive with 4 unrelated ids at 100 Hz: ~40 % of the frames unused."""
    d = tmp_path_factory.mktemp("bulk")
    frames, _ = simulate(paper, "paper", seed=3, noise="realistic", duration=30.0, extra_ids=4, extra_rate=100.0)
    write_log(frames, d / "mixed.log")
    return d / "mixed.log"


def vectorised(caplog) -> bool:
    """Neither the whole log nor any block went the per-frame way."""
    return "frame by frame" not in caplog.text


def test_same_estimates_stats_and_samples_as_the_per_frame_path(mixed, paper, monkeypatch, caplog):
    monkeypatch.setattr(bulk.source, "BLOCK", 1 << 16)  # many blocks: lines and ticks cross their ends
    with caplog.at_level(logging.DEBUG, logger="vdp.io.bulk"):
        (a, pa), (b, pb) = both(mixed, paper)
    assert vectorised(caplog)
    assert b == a
    assert a["log"]["decode"]["errors_by_kind"]["unknown_id"] > 0.35 * a["log"]["frames"]
    assert a["parameters"]["l_f"]["status"] == "converged"  # something was estimated at all
    assert list(pb.estimator.trace) == list(pa.estimator.trace)
    assert (pb.samples, pb.frames, pb.last_bus_time) == (pa.samples, pa.frames, pa.last_bus_time)
    assert pb.aligner._t == pa.aligner._t and pb.aligner._emitted == pa.aligner._emitted


def test_gzip_and_a_gap_in_bus_time(mixed, paper, tmp_path, caplog):
    lines = mixed.read_bytes().splitlines(keepends=True)
    half = len(lines) // 2
    shifted = []
    for ln in lines[half:]:  # 5 s of silence in the middle: the aligner restarts its grid
        ts, rest = ln.split(b" ", 1)
        shifted.append(b"(%.6f) " % (float(ts[1:-1]) + 5.0) + rest)
    path = tmp_path / "gap.log.gz"
    path.write_bytes(gzip.compress(b"".join(lines[:half] + shifted)))
    with caplog.at_level(logging.DEBUG, logger="vdp.io.bulk"):
        (a, pa), (b, pb) = both(path, paper)
    assert vectorised(caplog)
    assert b == a and a["log"]["clock"]["jumps"] == 1
    assert list(pb.estimator.trace) == list(pa.estimator.trace)


def test_bad_counters_and_checksums_are_counted_as_the_decoder_does(mixed, paper, tmp_path, monkeypatch, caplog):
    monkeypatch.setattr(bulk.source, "BLOCK", 1 << 16)
    lines = mixed.read_bytes().splitlines(keepends=True)
    out = []
    for i, ln in enumerate(lines):
        if b" 0B1#" in ln and i % 97 == 0:  # a wheel-speed frame now and then: break its checksum byte
            ln = ln[:-3] + (b"00" if ln[-3:-1] != b"00" else b"11") + b"\n"
        out.append(ln)
    path = tmp_path / "bad.log"
    path.write_bytes(b"".join(out))
    with caplog.at_level(logging.DEBUG, logger="vdp.io.bulk"):
        (a, _), (b, _) = both(path, paper)
    assert a["log"]["decode"]["errors_by_kind"].get("checksum", 0) > 0
    assert b == a
    # the blocks with a bad frame go frame by frame, the log as a whole does not
    assert "checksum failure" in caplog.text and "replaying it frame by frame" not in caplog.text


def test_a_damaged_log_is_replayed_frame_by_frame(mixed, paper, tmp_path, caplog):
    lines = mixed.read_bytes().splitlines(keepends=True)
    lines[len(lines) // 3] = b"garbage line\n"
    lines[len(lines) // 2] = b"(1.000000) can0 0B1#0011223344556677\n"  # far behind the clock
    path = tmp_path / "damaged.log"
    path.write_bytes(b"".join(lines))
    with pytest.raises(Irregular):
        src = BulkSource(path)
        src.feed_into(Pipeline(paper, EstimatorConfig(baseline=False)))
    with caplog.at_level(logging.INFO, logger="vdp.replay"):
        (a, _), (b, _) = both(path, paper)
    assert b == a and a["log"]["bad_lines"] == 2
    assert "frame by frame" in caplog.text


@pytest.mark.slow
def test_a_car_with_sign_and_fine_signals(repo_root, tmp_path, caplog):
    """opendbc layouts: the VW's sign bits, the RAV4's coarse + fine steering angle."""
    pytest.importorskip("opendbc")
    from vdp.sim.addons import CAR_TRUTH, with_addons

    for car in ("vw_golf_mk7", "toyota_rav4"):
        prof = with_addons(load_profile(repo_root / "profiles" / f"{car}.toml"))
        frames, _ = simulate(prof, "paper", seed=1, noise="realistic", duration=25.0, params=CAR_TRUTH[car])
        path = tmp_path / f"{car}.log"
        write_log(frames, path)
        caplog.clear()
        with caplog.at_level(logging.DEBUG, logger="vdp.io.bulk"):
            (a, pa), (b, pb) = both(path, prof)
        assert vectorised(caplog), car
        assert b == a, car
        assert list(pb.estimator.trace) == list(pa.estimator.trace), car


def test_a_layout_read_differently_from_the_decoder_goes_frame_by_frame(mixed, paper, monkeypatch, caplog):
    real = bulk._Plan.extract

    def off_by_one(self, b):
        vals, bad = real(self, b)
        return [v + 1 for v in vals], bad

    monkeypatch.setattr(bulk._Plan, "extract", off_by_one)
    with caplog.at_level(logging.DEBUG, logger="vdp.io.bulk"):
        (a, _), (b, _) = both(mixed, paper)
    assert "block and frame decoders disagree" in caplog.text
    assert b == a


def test_a_flood_of_unknown_ids_is_counted_not_stored(mixed, paper, tmp_path, monkeypatch, caplog):
    """Beyond the caps (here 200 ids in the reader's tables, 100 in the decoder's), the frames of
    further unknown ids are counted in one number: the tables stay bounded and the document is
    the per-frame path's (same totals, same top ids; only how many were passed over differs)."""
    from vdp.io import decoder

    monkeypatch.setattr(bulk.source, "BLOCK", 1 << 16)
    monkeypatch.setattr(bulk.source, "_ID_CACHE_MAX", 200)
    monkeypatch.setattr(bulk.decode, "MAX_UNKNOWN", 100)
    monkeypatch.setattr(decoder.frames, "MAX_UNKNOWN", 100)
    out = []
    for i, ln in enumerate(mixed.read_bytes().splitlines(keepends=True)):
        out.append(ln)
        if i % 3 == 0 and i < 12000:  # 600 distinct extended ids, a few frames each, in time order
            out.append(ln.split(b" ")[0] + b" can0 %08X#00\n" % (0x100000 + (i // 3) % 600))
    path = tmp_path / "flood.log"
    path.write_bytes(b"".join(out))
    with caplog.at_level(logging.DEBUG, logger="vdp.io.bulk"):
        (a, _), (b, pb) = both(path, paper)
    assert vectorised(caplog)
    # the per-frame reader hands out the first frame of each of the 604 unused ids (the log's 4
    # and the 600), the bulk one of the first 200 only and passes over the rest
    passed = a["log"].pop("passed_over"), b["log"].pop("passed_over")
    assert passed[1] - passed[0] == 404
    assert b == a
    dec = a["log"]["decode"]
    assert dec["unknown_distinct"] == 100 and dec["unknown_untracked"] > 0
    src = BulkSource(path)
    src.keep_ids(pb.decoder.ids)
    pipe = Pipeline(paper, EstimatorConfig(baseline=False))
    src.feed_into(pipe)
    assert len(src.stats.passed_over) <= 200 and src.stats.passed_over_other > 0
    assert len(pipe.decoder.stats.unknown) == 100
