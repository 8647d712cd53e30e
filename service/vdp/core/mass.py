"""Mass as an estimate (issue 28, part 1): the longitudinal force balance, learnt as the car is driven.

Summed over both axles, eq (1)-(2) with drag and rolling resistance:

    (T_f + T_r) / r - (2 J / r^2) dv/dt = m (dv/dt + g sin theta) + c_0 + c_2 v^2

``dv/dt + g sin theta`` is what a road-aligned accelerometer reads, a_x (the specific force),
so the grade needs no separate sensor: ``m a_x + c_0 + c_2 v^2 = F``, linear in
``[m, c_0, c_2]`` (Bae, Ryu and Gerdes 2001; Vahidi et al. 2005 estimate the grade beside
the mass with a second forgetting factor; here the accelerometer carries it).  A body-fixed
accelerometer reads ``(1 + kappa) f_x`` plus its mounting offset; with core.road on, a_x
comes in already divided by ``1 + kappa`` (learnt there from the GNSS speed's slope); with it
off, the learner keeps its own :class:`core.road.Pitch` on the raw a_x and the GNSS speed, and
the balance's ``m / (1 + kappa)`` is multiplied back by ``1 + kappa`` (:meth:`MassLearner.value`).
The offset times m is a constant force and goes into ``c_0``.  dv/dt, in the wheels' inertia
term only (13 kg on the paper car), is the GNSS speed's slope.

The filter works on rows of ``ROW`` seconds (means of F, a_x, v^2), recursive least squares in
its Kalman form: the parameters walk slowly (``Q``, the forgetting), the row's noise ``R`` is
scaled by the residuals it sees (a drive whose model fits worse than assumed gets a wider std,
never a narrower one), and the std is widened by the residuals' correlation from row to row
(``sqrt((1 + rho) / (1 - rho))``: what the rows hold is fewer independent rows than counted).
Rows are left out (counted by reason): below ``MIN_SPEED``, turning (tyre drag from slip
angles is not in the balance), beyond ``MAX_ACCEL`` (slip, ABS and traction control), or
with a torque or a_x missing.

The prior is the profile's mass: kerb weight plus a driver, with a std of ``PRIOR_REL``
(12 %): two passengers and luggage, 150-300 kg, lie within 2 sigma.  The estimate is valid
once its std is within ``USEFUL_REL`` (1.5 %, so that 2 sigma is the issue's 3 %) from at
least ``MIN_ROWS`` rows with acceleration or braking in them.

How the mass reaches the six parameters (first order, :func:`scaled`): stage 1 sees the
axle loads only as ``m (g l_r - a_x h) / L`` against forces from the torques, so it
identifies ``C_K m``, and l_f and h not at all through m; stage 2 sees ``C_alpha / m`` and
``I_z / m`` (eq 5-10 divided by m; the roll row driven by the measured a_y takes m h with
k_phi known, so I_x does not scale).  The estimator runs with the profile's mass and
:func:`scaled` puts the learnt mass in afterwards, so no filter restarts when it moves:
``C_K m_used / m``, ``C_alpha m / m_used``, ``I_z m / m_used``, each with the mass's relative
std added in quadrature; I_x keeps its value and takes the mass's relative change and std
into its std.  A load that moves the CG shows in l_f, h and I_z as the loaded car's values:
stage 1 and 2 see the car as driven.

Across restarts (``vdp serve``): :meth:`MassLearner.state` is kept in the store with the six
learners' own state (TwoStageEstimator.learnt) and :meth:`MassLearner.load` takes it back, so a
restart carries on from the mass learnt, its std and its residual statistics, not the prior.
A restore takes published values back into the filters through :func:`unscaled`, the inverse
of :func:`scaled`.

Pure: ``handle(t, sample)`` (and ``handle_block``, by the same step), ``snapshot()``, ``reset()``,
``state()``, ``load(state)``.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, replace

import numpy as np

from .. import channels as ch
from .params import MASS
from .result import CONVERGED, INVALID, NOT_RUN, UNCERTAIN, Estimate
from .road import ROW as ROAD_ROW
from .road import Pitch

log = logging.getLogger(__name__)

NAME = MASS
UNIT = "kg"
ROW = 1.0  # s per row
PRIOR_REL = 0.12
USEFUL_REL = 0.015
CONVERGED_REL = 0.01
MIN_ROWS = 20  # rows with |a_x| above EXCITED
EXCITED = 0.3  # m/s^2
MIN_SPEED = 3.0  # m/s
MAX_ACCEL = 4.0  # m/s^2
MAX_LATERAL = 1.0  # m/s^2 of v r: a row turning harder has tyre drag the balance leaves out
# |r omega / v - 1| of any wheel beyond this: spinning or locked (stage 1's LearnerConfig.spin_slip).  The
# balance takes the wheels' inertia at the body's acceleration; a wheel spinning up to hundreds of rad/s
# puts its J omega_dot into the torque, and without this gate the test's FWD car read 2,825 kg for 1,600.
SPIN_SLIP = 0.2
SIGMA_F = 40.0  # N: a row's force noise before the residuals say otherwise
# An IMU fixed to the body reads (1 + kappa) times the specific force, kappa = g x the body's pitch per
# m/s^2 (about 0.2 deg: issue 28), so the balance reads m / (1 + kappa): the vdp and brush models' body-fixed
# IMUs gave -2.5...-3.3 %, "valid" at 7-21 std, before this term.  Without the road model (core.road.Tilt)
# the learner's own core.road.Pitch learns kappa from the GNSS speed, from this prior std (0.034 at 0.2 deg);
# without a GNSS speed the mass's std carries all of it.
KAPPA_TYPICAL = 0.034
# A learnt mass known to this (relative, with KAPPA_TYPICAL in it) is put into the six in mode auto: one
# known worse could not leave C_K, C_alpha or I_z within their 5 % (params: useful_rel) anyway.
PUT_REL = 0.05
LO, HI = 300.0, 10000.0  # kg: a sane mass
STAGE = 0  # not a stage of the paper's: every sample, before both


@dataclass(frozen=True)
class MassConfig:
    """How the six take the mass (``mode``, one of MODES):

    - ``auto`` (the default): learnt; the profile's mass is kept while the drive's agrees with it within
      2 of its stds, and beyond, the learnt one comes in once known to PUT_REL (before that the six's
      stds widen by the excess): an undeclared load never shows as a confident wrong C_K, C_alpha or
      I_z (:func:`_put`);
    - ``on``: put in from the first sample: the six carry the prior's 12 % until the mass is known;
    - ``report``: learnt and published, never put in (the profile's mass taken as known);
    - ``off``: neither learnt nor put in: the profile's mass is taken as weighed as driven.
    """

    mode: str = "auto"
    # the IMU's pitch gain (relative) the mass's std carries where the road model does not learn it
    # (KAPPA_TYPICAL); 0 for an IMU known to stay level with the road (a test rig's, synthetic data)
    imu_tilt: float = KAPPA_TYPICAL

    def __post_init__(self):
        if self.mode not in MODES:
            raise ValueError(f"mass mode {self.mode!r}: one of {', '.join(MODES)}")

    @property
    def learn(self) -> bool:
        return self.mode != "off"

    @property
    def put(self) -> bool:
        """Whether the learnt mass goes into the six (scaled, unscaled)."""
        return self.mode in ("auto", "on")

    @property
    def auto(self) -> bool:
        return self.mode == "auto"


MODES = ("auto", "on", "report", "off")


class MassLearner:
    """Recursive least squares on ``[m, c_0, c_2]`` over rows of ROW seconds (see the module)."""

    def __init__(self, vehicle, cfg: MassConfig | None = None, tilt=None):
        self.vehicle = vehicle
        self.tilt = tilt  # core.road.Tilt: a_x comes divided by its 1 + kappa, whose std the mass takes
        self.cfg = cfg or MassConfig()
        # the road model off: the pitch gain learnt here, from the raw a_x and the GNSS speed (the module)
        self.pitch = Pitch(self.cfg.imu_tilt) if tilt is None and self.cfg.imu_tilt > 0 else None
        self.m0 = float(vehicle.mass)
        self.reset()

    def reset(self) -> None:
        m0, g = self.m0, self.vehicle.g
        self.x = np.array([m0, 0.012 * m0 * g, 0.35])
        self.P = np.diag([(PRIOR_REL * m0) ** 2, (0.02 * m0 * g) ** 2, 0.5**2])
        self.Q = np.diag([0.2**2, 2.0**2, 0.002**2]) * ROW  # per row: the slow walk (the forgetting)
        self.rows = 0
        self.excited = 0
        self.skipped: dict[str, int] = {}
        self._row: list | None = None
        self._chi = 1.0  # the residuals' mean chi^2 per row (EWMA): scales R
        self._rho = 0.0  # their lag-1 correlation (EWMA)
        self._last_e: float | None = None
        self._var = 1.0
        self.driven = 0.0  # s of samples seen, gaps left out: the drive's time
        self._t: float | None = None  # the last sample's
        self.valid_after: float | None = None  # s of drive (driven) until the mass first read valid
        if self.pitch is not None:
            self.pitch.reset()

    # -- across restarts ----------------------------------------------------------
    def state(self) -> dict:
        """What :meth:`load` takes back: the filter, its counts and its residuals' statistics (a row
        still open is not kept: at most ROW seconds, and a restart begins with a gap anyway)."""
        return {
            "m0": self.m0,
            "x": [float(v) for v in self.x],
            "P": np.asarray(self.P, dtype=float).tolist(),
            "rows": self.rows,
            "excited": self.excited,
            "skipped": dict(self.skipped),
            "chi": self._chi,
            "rho": self._rho,
            "last_e": self._last_e,
            "var": self._var,
            "driven": self.driven,
            "valid_after": self.valid_after,
            **({"pitch": self.pitch.saved()} if self.pitch is not None else {}),
        }

    def load(self, st) -> bool:
        """Carry on from :meth:`state` (a restart).  False, and the learner left as it was, for a
        state learnt with another profile mass (the prior it started from) or one damaged."""
        try:
            x, P = np.asarray(st["x"], dtype=float), np.asarray(st["P"], dtype=float)
            m0, rows, excited = float(st["m0"]), int(st["rows"]), int(st["excited"])
            chi, rho, var = float(st["chi"]), float(st["rho"]), float(st["var"])
            last_e = None if st.get("last_e") is None else float(st["last_e"])
            after = None if st.get("valid_after") is None else float(st["valid_after"])
            driven = float(st.get("driven") or 0.0)
            skipped = {str(k): int(v) for k, v in (st.get("skipped") or {}).items()}
        except (KeyError, TypeError, ValueError, AttributeError):
            return False
        if not math.isclose(m0, self.m0, rel_tol=1e-12) or x.shape != (3,) or P.shape != (3, 3):
            return False
        if not (np.all(np.isfinite(x)) and np.all(np.isfinite(P)) and all(map(math.isfinite, (chi, rho, var)))):
            return False
        if rows < 0 or not 0 <= excited <= rows or P[0, 0] <= 0.0:
            return False
        self.x, self.P, self.rows, self.excited, self.skipped = x, P, rows, excited, skipped
        self._chi, self._rho, self._var, self._last_e = chi, rho, var, last_e
        self.valid_after, self.driven, self._t = after, driven, None
        self._row = None
        # the pitch gain carries on too (a state without it, or one damaged: learnt afresh)
        if self.pitch is not None and not self.pitch.restore(st.get("pitch")):
            self.pitch.reset()
        return True

    # -- samples ---------------------------------------------------------------
    def handle(self, t: float, s) -> None:
        """One sample (derived: its ``v_x`` and ``yaw_bias`` set by the estimator)."""
        y = s.values
        v = y[ch.SPEED]
        v = v if math.isfinite(v) else s.v_x
        slip = _slip(y[ch.WS_FL], y[ch.WS_FR], y[ch.WS_RL], y[ch.WS_RR], v, self.vehicle.wheel_radius)
        self._add(t, y[ch.T_F], y[ch.T_R], y[ch.AX], v, y[ch.YAW] - s.yaw_bias, slip, s.gap)
        if self.pitch is not None:
            self.pitch.add(t, s.gap, y[ch.AX], y[ch.SPEED], s.fresh[ch.SPEED], s.age[ch.SPEED])

    def handle_block(
        self, T: np.ndarray, Y: np.ndarray, F: np.ndarray, A: np.ndarray, gap: bool, v_x: np.ndarray,
        yaw_bias: np.ndarray,
    ) -> None:  # fmt: skip
        """A block of samples (TwoStageEstimator.handle_block's: ticks, values, fresh and ages by channel,
        with the speed filter's ``v_x`` and the gyro's ``yaw_bias`` per sample): what :meth:`handle` on
        each does, by the same steps."""
        if not len(T):
            return
        v = Y[:, ch.SPEED]
        v = np.where(np.isfinite(v), v, v_x)
        wz = Y[:, ch.YAW] - yaw_bias
        rad = self.vehicle.wheel_radius
        add = self._add
        cols = (
            T,
            Y[:, ch.T_F],
            Y[:, ch.T_R],
            Y[:, ch.AX],
            v,
            wz,
            *(Y[:, c] for c in (ch.WS_FL, ch.WS_FR, ch.WS_RL, ch.WS_RR)),
        )
        if self.pitch is None:
            for k, (t, tf, tr, ax, vk, w, fl, fr, rl, rr) in enumerate(zip(*(c.tolist() for c in cols))):
                add(t, tf, tr, ax, vk, w, _slip(fl, fr, rl, rr, vk, rad), gap and k == 0)
            return
        # the pitch gain's step after the mass's, sample by sample, as handle does (a row's verdict reads it)
        padd = self.pitch.add
        cols += (Y[:, ch.SPEED], F[:, ch.SPEED], A[:, ch.SPEED])
        for k, (t, tf, tr, ax, vk, w, fl, fr, rl, rr, g, fg, ag) in enumerate(zip(*(c.tolist() for c in cols))):
            add(t, tf, tr, ax, vk, w, _slip(fl, fr, rl, rr, vk, rad), gap and k == 0)
            padd(t, gap and k == 0, ax, g, fg, ag)

    def _add(self, t: float, tf: float, tr: float, ax: float, v: float, wz: float, slip: float, gap: bool) -> None:
        """A sample into the open row (rows of ROW seconds from their first sample; a gap drops the
        open row unclosed; a row with a missing torque or a_x is skipped as a whole; ``slip``: the
        wheels' largest, :func:`_slip`)."""
        if not gap and self._t is not None and 0.0 < t - self._t < ROW:
            self.driven += t - self._t
        self._t = t
        r = self._row
        if gap or r is None or t - r[0] >= ROW:
            if r is not None and not gap:
                self._close(r)
            r = self._row = [t, 0, 0.0, 0.0, 0.0, 0.0, 0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
        if not (math.isfinite(tf) and math.isfinite(tr) and math.isfinite(ax)):
            r[1] = -1_000_000  # a row with a missing value: skipped as a whole
            return
        r[1] += 1
        r[2] += (tf + tr) / self.vehicle.wheel_radius
        r[3] += ax
        # turning, by the yaw rate (a bank reads in a_y, not in it)
        r[4] += abs(wz * v) if math.isfinite(wz) and math.isfinite(v) else 0.0
        if math.isfinite(v):
            dt = t - r[0]
            r[5] += v * v
            r[6] += 1
            r[7] += dt
            r[8] += v
            r[9] += dt * dt
            r[10] += dt * v
        r[11] = max(r[11], abs(ax))
        r[12] = max(r[12], slip)

    def _skip(self, why: str) -> None:
        self.skipped[why] = self.skipped.get(why, 0) + 1

    def _close(self, r: list) -> None:
        t0, n, F, ax, ay, v2, nv, st, sv, stt, stv, amax, slip = r
        if n < 5:
            self._skip("missing torque or a_x")
            return
        if nv < 3:
            self._skip("no speed")
            return
        if sv / nv < MIN_SPEED:
            self._skip("standstill or creep")
            return
        if ay / n > MAX_LATERAL:
            self._skip("turning")
            return
        if amax > MAX_ACCEL:
            self._skip("beyond the small-slip range")
            return
        if slip > SPIN_SLIP:
            self._skip("wheel spin or lock")
            return
        F, ax, v2 = F / n, ax / n, v2 / nv
        d = nv * stt - st * st
        dvdt = (nv * stv - st * sv) / d if d > 0 else ax
        veh = self.vehicle
        y = F - 2.0 * veh.wheel_inertia / veh.wheel_radius**2 * dvdt  # eq 2: the wheels' own inertia
        H = np.array([ax, 1.0, v2])
        self.P = self.P + self.Q
        R = SIGMA_F**2 * max(self._chi, 1.0)
        S = float(H @ self.P @ H) + R
        e = y - float(H @ self.x)
        if e * e > 25.0 * S and self.rows > 10:
            self._skip("outlier (5 sigma)")
            return
        K = self.P @ H / S
        self.x = self.x + K * e
        self.P = self.P - np.outer(K, H @ self.P)
        self.rows += 1
        self.excited += abs(ax) > EXCITED
        # the residuals' scale and correlation, for an honest std
        z = e * e / S
        a = 0.02 if self.rows > 50 else 1.0 / self.rows
        self._chi += a * (z * max(self._chi, 1.0) - self._chi)
        if self._last_e is not None:
            self._rho += a * (e * self._last_e / max(self._var, 1e-9) - self._rho)
        self._var += a * (e * e - self._var)
        self._last_e = e
        if self.valid_after is None and self.excited >= MIN_ROWS:
            m, sd = self.value()
            if LO <= m <= HI and sd <= USEFUL_REL * m:
                self.valid_after = self.driven

    # -- results -----------------------------------------------------------------
    def value(self) -> tuple[float, float]:
        """(mass, its honest std) [kg]."""
        rho = min(max(self._rho, 0.0), 0.9)
        sd = math.sqrt(max(self.P[0, 0], 0.0)) * math.sqrt((1.0 + rho) / (1.0 - rho))
        m = float(self.x[0])
        # m a_x / (1 + kappa): kappa's std is the mass's, relative: learnt with the road model or here
        # (the balance then holds m / (1 + kappa), multiplied back), else all of the typical one
        if self.pitch is not None:
            k = 1.0 + self.pitch.kappa
            m, sd = m * k, sd * k
        ks = self.tilt.kappa_std if self.tilt is not None else self.pitch.kappa_std if self.pitch else 0.0
        return m, math.hypot(sd, m * ks)

    def snapshot(self) -> Estimate:
        m, sd = self.value()
        prior_sd = PRIOR_REL * self.m0
        progress = 0.0
        # (a mass of no car's, e.g. negative from a sign-flipped a_x, has no progress: it is invalid below)
        if 0.0 < sd < prior_sd and USEFUL_REL * m > 0.0 and prior_sd > USEFUL_REL * m:
            progress = min(math.log(prior_sd / sd) / math.log(prior_sd / (USEFUL_REL * m)), 1.0)
        extra = {
            "rows": self.rows,
            "rows_excited": self.excited,
            "rolling_resistance_N": round(float(self.x[1]), 1),
            "drag_N_per_mps2": round(float(self.x[2]), 4),
            "residual_chi2": round(self._chi, 3),
            "residual_corr": round(self._rho, 3),
            "profile_mass": self.m0,
            "driven_s": round(self.driven, 1),
            "valid_after_s": None if self.valid_after is None else round(self.valid_after, 1),
        }
        if self.pitch is not None:
            extra.update(pitch_gain_kappa=round(self.pitch.kappa, 5), pitch_gain_std=round(self.pitch.kappa_std, 5),
                         pitch_level_rows=self.pitch.level_rows)  # fmt: skip
        extra.update({f"skipped_{k.replace(' ', '_')}": v for k, v in self.skipped.items()})
        if self.rows == 0:
            why = "no straight driving with torques yet: the profile's mass"
            if self.skipped:  # what the drive had, and why none of it taught the mass
                left = ", ".join(f"{k} {v}" for k, v in sorted(self.skipped.items(), key=lambda kv: -kv[1]))
                why += f" (rows of {ROW:g} s left out: {left})"
                if "no speed" in self.skipped:
                    why += "; the balance needs a speed: the GNSS speed, or the speed filter's from a free-rolling axle"
            return Estimate(NAME, self.m0, prior_sd, UNIT, NOT_RUN, False, STAGE, 0, reason=why, progress=0.0,
                            hint="drive: accelerate and brake on a straight road", extra=extra)  # fmt: skip
        if not LO <= m <= HI:
            return Estimate(NAME, m, sd, UNIT, INVALID, False, STAGE, self.rows,
                            reason=f"{m:.0f} kg is no car's: check the axle torques' scale", extra=extra)  # fmt: skip
        valid = sd <= USEFUL_REL * m and self.excited >= MIN_ROWS
        status = CONVERGED if valid and sd <= CONVERGED_REL * m else UNCERTAIN
        reason = None
        if not valid:
            reason = (f"known to +-{100 * sd / m:.1f} % from {self.excited} s of acceleration or braking; "
                      f"valid within {100 * USEFUL_REL:g} % and after {MIN_ROWS} s")  # fmt: skip
            ks = self.pitch.kappa_std if self.pitch is not None else 0.0
            if ks > 0.5 * USEFUL_REL:
                # the IMU's pitch gain is learnt on level road with a GNSS speed (core.road.Pitch)
                rows = self.pitch.level_rows
                reason += (f", and {100 * ks:.1f} % of it is the IMU's pitch with the body, learnt from the "
                           f"GNSS speed on level road ({rows} rows of {ROAD_ROW:g} s so far)")  # fmt: skip
        return Estimate(NAME, m, sd, UNIT, status, valid, STAGE, self.rows, reason=reason,
                        progress=round(progress, 3), extra=extra)  # fmt: skip


OFF_REASON = (
    "not estimated: mass estimation is off, so the profile's vehicle.mass ({m:g} kg) is taken as known and a load "
    'is not seen; turn it on to learn the mass as driven (vdp replay --mass auto; vdp serve: [service] mass = "auto")'
)


def _slip(fl: float, fr: float, rl: float, rr: float, v: float, radius: float) -> float:
    """The largest |r omega / v - 1| of the wheels with a speed (0 below MIN_SPEED or without v)."""
    if not (math.isfinite(v) and v >= MIN_SPEED):
        return 0.0
    out = 0.0
    for w in (fl, fr, rl, rr):
        out = max(out, abs(w * radius / v - 1.0))  # (max(out, NaN) is out: a wheel without a speed)
    return out


def off(m0: float) -> Estimate:
    """The mass where its estimation is off: said (not_run, the reason), never left out silently.
    Value and std are the prior's, as the learner's own before its first row: the profile's mass,
    which every parameter is taken with, and PRIOR_REL, what an unseen load may make of it."""
    return Estimate(NAME, float(m0), PRIOR_REL * float(m0), UNIT, NOT_RUN, False, STAGE, 0,
                    reason=OFF_REASON.format(m=m0), progress=0.0,
                    extra={"profile_mass": float(m0), "estimated": False})  # fmt: skip


# -- the mass into the six ---------------------------------------------------------------
SCALE = {"C_K": -1, "C_alpha": 1, "I_z": 1}  # the power of m each parameter scales with
USEFUL = {"l_f": 0.02, "h": 0.05, "C_K": 0.05, "C_alpha": 0.05, "I_z": 0.05, "I_x": 0.10}  # params.SPECS' useful_rel


def _put(mass: Estimate, m_used: float, auto: bool) -> tuple[float, float, str]:
    """(mass ratio, relative std, what it is) that the six are published with.

    Mode on (``auto`` False): a learnt mass known to PUT_REL (from MIN_ROWS rows of acceleration or
    braking), its own, with its std; before that the profile's mass, with the prior's std.

    Mode auto: the profile's mass as declared while the drive's mass agrees with it within 2 of its
    stds (the six as learnt, bit for bit: a known mass that agrees would only add its std, 3.4 % or
    more without the road model).  Beyond, where the learnt mass is known, it comes in on a ramp
    from 2 to 3 of its stds (ratio 1 + w (m / m_used - 1), the std w of its own and 1 - w of the
    excess beyond 2 stds: no jump in either); where it is not known yet, the profile's mass stays
    and the std takes the excess: a mass that already says the car is 300 kg heavier than its
    profile must not leave C_K +18 % "valid" (BENCHMARKS.md, load).
    """
    m, sd = mass.value, mass.std
    known = mass.status in (CONVERGED, UNCERTAIN) and m is not None and sd is not None
    known = known and m > 0 and math.isfinite(m) and math.isfinite(sd)
    known = known and sd <= PUT_REL * m and (mass.extra or {}).get("rows_excited", MIN_ROWS) >= MIN_ROWS
    if not auto:
        return (m / m_used, sd / m, "learnt") if known else (1.0, PRIOR_REL, "the prior")
    if mass.status == NOT_RUN or m is None or sd is None or not (m != 0 and math.isfinite(m) and math.isfinite(sd)):
        return 1.0, 0.0, "the profile's"
    # (a mass of no car's, negative from a sign-flipped a_x or tiny from a torque's scale, departs the most)
    rel, d = sd / abs(m), abs(m / m_used - 1.0)
    excess = max(0.0, d - 2.0 * rel)
    if not known or excess == 0.0:
        return 1.0, excess, "the profile's"
    w = min(1.0, excess / rel)
    return 1.0 + w * (m / m_used - 1.0), math.hypot(w * rel, (1.0 - w) * excess), "learnt"


def scaled(params: dict, mass: Estimate, m_used: float, auto: bool = False) -> dict:
    """The six estimates with the learnt mass put in (see the module), and its std carried.

    Which mass and what std the six take (:func:`_put`): mode on, the learnt mass once known to
    PUT_REL, the profile's with the prior's 12 % before; mode ``auto``, the profile's while the
    drive's mass agrees with it, the learnt one beyond 2 of its stds.
    """
    ratio, rel_m, what = _put(mass, m_used, auto)
    if not m_used > 0 or (ratio == 1.0 and rel_m == 0.0):  # (auto, the mass agreeing: the six as learnt)
        return params
    m = m_used * ratio
    out = dict(params)
    for name, e in params.items():
        if e.value is None or e.std is None or e.status == NOT_RUN:
            continue
        if name in SCALE:
            f = ratio ** SCALE[name]
            value, rel = e.value * f, math.hypot(e.std / abs(e.value), rel_m) if e.value else math.inf
        elif name == "I_x":
            value, rel = e.value, math.hypot(e.std / abs(e.value), rel_m, ratio - 1.0) if e.value else math.inf
        else:
            continue
        std = rel * abs(value)
        valid = e.valid and rel <= USEFUL.get(name, 0.05)
        why = e.reason
        if e.valid and not valid:
            if what == "the profile's":
                why = (f"the drive's mass reads {mass.value:.0f} ± {mass.std:.0f} kg against the profile's "
                       f"{m_used:.0f} kg (not yet known to {100 * PUT_REL:g} %): {100 * rel_m:.1f} % carried "
                       f"until it is, then put in")  # fmt: skip
            else:
                why = f"the mass is known to +-{100 * rel_m:.1f} % only ({what})"
        if what == "the profile's":  # (the mass not put in: C_K's step across drives is still a load's)
            extra = {**e.extra, "mass_departure": round(rel_m, 4)}
        else:
            extra = {**e.extra, "mass_used": round(m, 1), "mass_ratio": round(ratio, 4), "mass_source": what}
        if name == "C_alpha":
            extra.update(_axles(e.extra, ratio, rel_m))
        out[name] = replace(e, value=value, std=std, valid=valid, reason=why, extra=extra)
    return out


def _axles(extra: dict, ratio: float, rel_m: float) -> dict:
    """C_alpha's per-axle numbers (learn.axles) scaled as C_alpha is, so their mean stays the
    published value; the front-minus-rear std scales with them (the mass is common to both)."""
    out = {}
    for axle in ("C_alpha_front", "C_alpha_rear"):
        v, sd = extra.get(axle), extra.get(axle + "_std")
        if v is None:
            continue
        out[axle] = v * ratio
        if sd is not None and v:
            out[axle + "_std"] = math.hypot(sd / abs(v), rel_m) * abs(v * ratio)
    d = extra.get("C_alpha_front_minus_rear_std")
    if d is not None:
        out["C_alpha_front_minus_rear_std"] = d * ratio
    return out


def unscaled(params: dict, mass: Estimate, m_used: float, auto: bool = False) -> dict:
    """The inverse of :func:`scaled`: the six as their learners hold them, from the six published
    with ``mass`` (a restore takes published values back into the filters, which run with the
    profile's mass).  A relative std narrower than the mass's share (values published without the
    mass: a store written with mass estimation off) keeps its own: the mass's is added again when
    published, never taken out twice."""
    ratio, rel_m, _ = _put(mass, m_used, auto)
    if not m_used > 0 or (ratio == 1.0 and rel_m == 0.0):
        return params
    out = dict(params)
    for name, e in params.items():
        if e.value is None or e.std is None or e.status == NOT_RUN or not e.value:
            continue
        if name in SCALE:
            value, share = e.value / ratio ** SCALE[name], rel_m * rel_m
        elif name == "I_x":
            value, share = e.value, rel_m * rel_m + (ratio - 1.0) ** 2
        else:
            continue
        rel = e.std / abs(e.value)
        own = math.sqrt(rel * rel - share) if rel * rel > share else rel
        out[name] = replace(e, value=value, std=own * abs(value))
    return out
