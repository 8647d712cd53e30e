"""The check of a log's first minutes: decoded through the profile, then checked (check_log, check_head)."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from .. import channels as ch
from ..errors import ProfileError
from ..profile import Profile
from .coverage import Coverage, check_refused, coverage
from .limits import check_bounds, check_brake_pressure, check_profile
from .report import Report
from .samples import CHECK_SECONDS, CHECKS, TICK, check_samples

log = logging.getLogger(__name__)


def check_log(
    path: str | Path,
    profile: Profile,
    seconds: float = CHECK_SECONDS,
    strict_coverage: bool = True,
    quiet: bool = False,
) -> tuple[Report, Coverage]:
    """Decode the first ``seconds`` of bus time of a log and check the profile against it.

    A log that holds none of the profile's messages, or fewer than half, is a ProfileError
    with the counts and the ids the log does hold (unless ``strict_coverage`` is false).
    ``quiet``: the reader logs no warnings (a replay that reads the log next gives them).
    """
    return check_head(first_seconds(path, profile, seconds, quiet), profile, strict_coverage, path)


def check_head(head: Head, profile: Profile, strict_coverage: bool = True, path: str | Path = "the log") -> tuple:
    """:func:`check_log` of a log's first seconds already read (:func:`first_seconds`); ``head``
    is left as it was (its samples serve the drive's measures too: across.measures_of)."""
    from ..io.logs import channel_keys

    dec, al, ts, y, st = head.decoder, head.aligner, head.t, head.y.copy(), head.stats
    cov = coverage(dec)
    if getattr(st, "skipped", 0):  # the log source left out the frames of other bus channels
        names = sorted(c for c in getattr(st, "channels", ()) if c not in channel_keys(profile.bus_channel))
        cov.other_channels = {", ".join(names) or "?": st.skipped}
    if strict_coverage and cov.seen * 2 < len(cov.wanted):
        raise ProfileError(f"{path}: the log does not fit profile {profile.path}: {cov.message()}")
    # a channel whose message is missing or refused for most frames (and no alternative stands in):
    # its few values are not judged, and its checks say why
    lost = {
        c: cm.message
        for c, cm in profile.channels.items()
        if cm.message in cov.missing and (cm.alt is None or cm.alt.message in cov.missing)
    }
    rep = Report()
    if len(ts):
        for c in lost:
            y[:, ch.INDEX[c]] = np.nan
        check_samples(profile, ts, y, rep)
    else:
        check_profile(profile, rep)
    check_bounds(al.refused, dec.stats.samples, rep)
    check_brake_pressure(profile, dec, rep)
    check_refused(profile, cov, dec.db, rep)
    for key, figure, needs, what in CHECKS:
        chans = [c for n in needs for c in (ch.NAMES[:4] if n == "wheel_speed" else (n,)) if c in lost]
        if figure not in rep.measured and chans:
            m = lost[chans[0]]
            how = "refused" if m in cov.refused else "missing"
            rep.skipped[key] = f"{what}: {chans[0]} had next to no values (its message {m} {how})"
    return rep, cov


class Head(NamedTuple):
    """A log's first seconds, decoded and aligned (:func:`first_seconds`)."""

    decoder: Any  # the FrameDecoder that read them (its counts per id: vdp.core.change.id_counts)
    aligner: Any
    t: np.ndarray  # sample times [s]
    y: np.ndarray  # sample values (one row per sample, channels.INDEX columns)
    stats: Any  # the reader's
    span: float  # bus time from the first frame read to the last [s]


def first_seconds(path: str | Path, profile: Profile, seconds: float = CHECK_SECONDS, quiet: bool = True) -> Head:
    """The first ``seconds`` of bus time of a log, decoded and aligned as the profile check reads
    them (the running service's self-check keeps its samples alike).  A candump log goes a block
    at a time where that pays (vdp.io.bulk, the same samples and decoder counts); one it hands
    back, a short one, and any other format, frame by frame.  Every frame reaches the decoder,
    those of ids it does not know included."""
    from ..buffer import Aligner
    from ..io import bulk
    from ..io.decoder import FrameDecoder
    from ..io.logs import open_log

    def fresh():
        dec = FrameDecoder(profile)
        stale = np.full(ch.N, 0.5)
        for name, cm in profile.channels.items():  # a 1 Hz GPS stays usable between its frames
            cycle = dec.db.get_message_by_name(cm.message).cycle_time
            if cycle:
                stale[ch.INDEX[name]] = max(5.0 * cycle / 1000.0, 0.5)
        return dec, Aligner(stale_after=stale, tick=TICK, limits=ch.limits(profile.vehicle))

    if bulk.pays(path):
        dec, al = fresh()
        sink = _Sink(dec, al)
        src = bulk.BulkSource(path, channel=profile.bus_channel, until=seconds, keep_all=True)
        try:
            src.feed_into(sink)
        except bulk.Irregular as why:
            log.debug("%s: %s; checking it frame by frame", path, why)
        else:
            return Head(dec, al, *sink.arrays(), src.stats, float(src.stats.bus_time or 0.0))
        finally:
            src.close()
    dec, al = fresh()
    ts: list[float] = []
    rows: list[tuple] = []
    t0 = t1 = None
    with open_log(path, channel=profile.bus_channel, quiet=quiet) as src:
        for msg in src:
            if t0 is None:
                t0 = msg.timestamp
            if msg.timestamp - t0 > seconds:
                break
            t1 = msg.timestamp
            pairs = dec.decode(msg)
            if pairs:
                for s in al.push(msg.timestamp, pairs):
                    ts.append(s.t)
                    rows.append(s.values)
    y = np.vstack(rows) if rows else np.zeros((0, ch.N))
    return Head(dec, al, np.asarray(ts), y, src.stats, (t1 - t0) if t0 is not None else 0.0)


class _Sink:
    """What the block reader feeds (a pipeline's decoder, aligner, feed and take_block): keeps
    the aligned samples, as the frame-by-frame loop of :func:`first_seconds` keeps them."""

    def __init__(self, decoder, aligner):
        self.decoder, self.aligner = decoder, aligner
        self.last_bus_time = None
        self._t: list[np.ndarray] = []
        self._y: list[np.ndarray] = []

    def feed(self, msg) -> None:
        pairs = self.decoder.decode(msg)
        if pairs:
            samples = self.aligner.push(msg.timestamp, pairs)
            if samples:
                self._t.append(np.array([s.t for s in samples]))
                self._y.append(np.array([s.values for s in samples]))

    def take_block(self, T, Y, F, A, gap) -> None:
        self._t.append(T)
        self._y.append(Y)

    def arrays(self) -> tuple[np.ndarray, np.ndarray]:
        if not self._t:
            return np.zeros(0), np.zeros((0, ch.N))
        return np.concatenate(self._t), np.vstack(self._y)
