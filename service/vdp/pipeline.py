"""The one pipeline, live or replay: frames -> decoder -> aligner -> ring -> estimator.

Only the frame source differs: ``vdp replay`` iterates a log file into
:meth:`Pipeline.feed`, ``vdp serve`` feeds it from a python-can Notifier.
"""

from __future__ import annotations

import logging
import math
import time

import numpy as np

from . import channels
from .buffer import Aligner, SampleRing
from .core import progress
from .core.estimator import EstimatorConfig, TwoStageEstimator
from .io.decoder import FrameDecoder, estimator_config
from .profile import Profile

log = logging.getLogger(__name__)

STALE_PERIODS = 5.0  # a channel silent this many cycle times is stale


class Pipeline:
    def __init__(self, profile: Profile, cfg: EstimatorConfig | None = None, ring_capacity: int = 3000):
        self.profile = profile
        self.decoder = FrameDecoder(profile)
        cfg = cfg or EstimatorConfig()
        # the speed reference this car has: GNSS at its resolution, or the free-rolling axle
        cfg = estimator_config(profile, self.decoder.db, cfg)
        self.estimator = TwoStageEstimator(profile.vehicle, profile.priors, cfg)
        self.aligner = Aligner(stale_after=self._stale_after(), tick=self.estimator.cfg.tick)
        self.ring = SampleRing(ring_capacity)
        self.frames = 0
        self.samples = 0
        self.started = time.monotonic()
        self.last_bus_time: float | None = None
        cap = self.capabilities()
        for stage, why in cap.items():
            if why:
                log.info("stage %s cannot run: %s", stage, why)

    def _stale_after(self) -> np.ndarray:
        out = np.full(channels.N, 0.1)
        for name, cm in self.profile.channels.items():
            try:
                cycle_ms = self.decoder.db.get_message_by_name(cm.message).cycle_time
            except KeyError:
                cycle_ms = None
            if cycle_ms:
                out[channels.INDEX[name]] = max(STALE_PERIODS * cycle_ms / 1000.0, 0.05)
        return out

    def capabilities(self) -> dict[str, str | None]:
        """Why each stage cannot run with this profile's channels (None: it can)."""
        out: dict[str, str | None] = {}
        for stage, needs in (("1", channels.STAGE1_NEEDS), ("2", channels.STAGE2_NEEDS)):
            missing = self.profile.missing(needs)
            if missing:
                what = list(dict.fromkeys(channels.DESCRIPTIONS[m] for m in missing))
                out[stage] = f"no {', no '.join(what)} (the profile maps no {', '.join(missing)})"
            else:
                out[stage] = None
        if out["1"]:
            tail = "it needs stage 1's l_f, h and C_K, and stage 1 cannot run"
            out["2"] = f"{out['2']}; and {tail}" if out["2"] else tail
        return out

    def feed(self, msg) -> None:
        """Consume one frame (a can.Message or anything with its attributes)."""
        self.frames += 1
        pairs = self.decoder.decode(msg)
        if not pairs:
            return
        t = msg.timestamp
        self.last_bus_time = t
        for s in self.aligner.push(t, pairs):
            self.samples += 1
            self.ring.append(s)
            self.estimator.handle(s.t, s)

    def pass_over(self, counts: dict[int, int]) -> None:
        """Count frames a source left out because no plan decodes their id (see LogSource.keep_ids)."""
        self.frames += sum(counts.values())
        self.decoder.stats.add_unknown(counts)

    def snapshot(self) -> dict:
        snap = self.estimator.snapshot()
        snap["capabilities"] = self.capabilities()
        # progress and coaching from what the learners have (core.progress)
        coach = progress.assess(snap, self.profile.priors, self.estimator.cfg.tick)
        for name, c in coach["parameters"].items():
            e = snap["parameters"].get(name)
            if e is not None:
                e["progress"], e["hint"] = c["progress"], c["hint"]
        snap["coaching"] = coach
        return snap

    def freshness(self) -> dict[str, dict]:
        """Each mapped channel's age at the newest bus time, and whether it is stale."""
        out = {}
        t = self.last_bus_time
        for name in self.profile.channels:
            i = channels.INDEX[name]
            newest = self.aligner.newest(i)
            age = (t - newest) if (t is not None and math.isfinite(newest)) else None
            out[name] = {"age": age, "stale": age is None or age > self.aligner.stale_after[i]}
        return out

    def reset(self, stage: int | None = None) -> None:
        self.estimator.reset(stage)
