"""Where stage 2's cornering stiffness goes wrong on the independent models.

    python benchmarks/stage2_mismatch.py fit [--cases brush/saloon,...]
    python benchmarks/stage2_mismatch.py replay [--cases ...] [--pin] [--no-roll] [--no-fxf] [--per-axle]
    python benchmarks/stage2_mismatch.py terms [--cases ...] [--terms base,curve,curve+roll,...]

``fit``: on the noise-free recorded drive (the traces benchmarks/independent.py records,
made here if missing), the stage-2 part from 62 s: the linear single-track model without
roll (eqs 5, 7, 10, 12 with F_xf left out), driven by the drive's road-wheel angle and
speed, is fitted by least squares to its yaw rate and a_y (weights 0.01 rad/s, 0.1 m/s^2)
over C_f, C_r and I_z.  Prints the residuals at the truth's values and the best fit as
multiples of the truth: what the best linear single track makes of the car.

``replay``: the noise-free drive through the replay pipeline; ``--pin`` hands stage 2 the
truth's l_f, h and C_K (stage 1's errors out of the way), ``--no-roll`` leaves the roll-rate
row out of stage 2's updates (what eq 9's roll model does to the other parameters),
``--no-fxf`` leaves the front longitudinal force out of stage 2's model (C_K = 0 there, as
the fit does: what the wheel-speed slip does to it).

``terms``: what physics the single track leaves out, term by term.  Each model drives
the ``stage2`` scenario (the same 0.1 Hz sawtooth, +-5 deg at 10 m/s, 52 s) once more,
this time with every tyre's load, slips, camber and forces recorded at the first
Runge-Kutta stage of every 5 ms sample (the models' own code, tapped; nothing
re-derived).  The same output-error fit is then repeated with known terms added to the
single track, one set per ``--terms`` group (``+`` joins terms, ``,`` separates groups):

* ``curve``: each axle's lateral force is the model's own tyre curve at the stage-2 mean
  axle loads (brush: the brush law; mb: the Magic Formula at zero camber), times the
  fitted factor, instead of C alpha: what tyre curvature does;
* ``fiala``: what an estimator could use instead: Fiala's law (the isotropic brush) per axle
  with the fitted C as its initial slope, mu = 1 and the stage-2 mean axle load;
* ``load``: each wheel's own curve at its recorded load (lateral and longitudinal load
  transfer; brush's stiffness is degressive in load, the Magic Formula's is
  proportional, so on mb this equals ``curve`` with the axle's momentary load);
* ``roll``: the sprung mass's roll swing in the lateral balance.  brush: m_s d phi''
  (the IMU and the axles sit on the roll axis, the sprung CG d above it); mb: the IMU
  and the tyres' kinematics sit on the sprung CG, and the unsprung masses swing
  relative to it, -(m_uf y_f'' + m_ur y_r'') (the library's compliant-joint states);
* ``mu``: Fiala's law with its friction coefficient fitted too (a fourth unknown: the
  curvature from the data, not assumed);
* ``swing``: a roll-sideslip coupling a_y += s phi'' with the length s fitted (brush's
  truth is m_s d / m; mb's, with the IMU and the tyres' kinematics on the sprung mass,
  near 0);
* ``rollcam``: a lateral force k m g phi with k fitted (camber thrust from roll, shared
  by the axles in proportion to their loads, so it adds no yaw moment; phi integrated
  from the roll-rate channel);
* ``rate``: a roll-rate slip q phi' / v_x on both axles' slip angles with the length q
  fitted (what mb's unsprung roll on its tyres does, as a single track could carry it);
* ``mh``: what an estimator could add with what it knows: m h phi'' in the lateral balance
  (eq 9's whole mass, stage 1's h as the truth has it, phi'' from the roll-rate channel);
* ``camber``: mb: each axle's camber thrust, F_y(gamma) - F_y(0) at the recorded
  slip and load (the library's Magic Formula shifts by sign(gamma) (p_hy1, p_vy1):
  a step of about 4 % of F_z per wheel when the camber changes sign);
* ``fx``: the longitudinal tyre forces: the front's F_x sin(delta) and the left-right
  F_x moment (rolling resistance and drive under load transfer);
* ``kin``: each wheel's recorded slip angle minus the single track's from the recorded
  states (track width, atan, and mb's unsprung roll-rate term); with ``load`` each wheel
  takes its own, otherwise the axle the mean of its two;
* ``arm``: mb: lever arms about the sprung CG (the library's yaw equation takes moments
  there, with I_z and no unsprung masses) instead of the static l_f, and the lateral
  balance's (m_ur b - m_uf a) r' that goes with that reference point;
* ``ay<X``: the residual only where |a_y| < X m/s^2 (the model still runs throughout).

``secant``: each axle's effective (secant) cornering stiffness in a steady turn at a_y =
1, 2, 3 m/s^2 as a multiple of the truth's, from the model's own tyre law: with both
wheels at the axle's mean load (curvature alone) / with the turn's lateral load transfer
(see :func:`secant`).

Each row gives C_f, C_r and I_z of the best fit as multiples of the truth's (the truth's
definitions in vdp.sim.independent.DEFINITIONS) and the rms misfit of yaw rate and a_y.
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "service"))
sys.path.insert(0, str(ROOT / "benchmarks"))

from independent import make_trace, trace_path  # noqa: E402

CASES = ("brush/saloon", "brush/small", "mb/bmw_320i", "mb/vw_vanagon")
T_STAGE2 = 62.0  # s: the paper drive's stage-2 part starts here
STEP = 5  # ms: the fit's integration step (semi-implicit Euler; the yaw modes are ~10x slower)


def _trace(case: str, cache: Path):
    from vdp.sim.independent.common import Trace

    make_trace((case, "paper", cache))
    return Trace.load(trace_path(cache, case, "paper"))


def _truth(case: str, cache: Path):
    """The truth file of the recorded paper drive: C_alpha at its stage-2 part's mean axle loads."""
    from vdp.sim.independent.common import IndependentSimulation

    model, car = case.split("/")
    s = IndependentSimulation(model, car, "paper", seed=1, noise="none", trace=_trace(case, cache))
    return s.truth, s.profile.vehicle


def single_track(theta, d, v_x, dt: float, m: float, L: float, l_f: float):
    """Yaw rate and a_y of the linear single track (no roll, no F_xf) from rest, per sample."""
    c_f, c_r, i_z = theta
    l_r = L - l_f
    v_y = r = 0.0
    yaw, a_y = np.empty(len(d)), np.empty(len(d))
    for i in range(len(d)):
        v, cd = v_x[i], math.cos(d[i])
        f_yf = c_f * (d[i] - (v_y + l_f * r) / v)
        f_yr = c_r * (l_r * r - v_y) / v
        ay = (f_yf * cd + f_yr) / m
        yaw[i], a_y[i] = r, ay
        v_y += dt * (ay - v * r)
        r += dt * (l_f * f_yf * cd - l_r * f_yr) / i_z
    return yaw, a_y


def fit(case: str, cache: Path) -> str:
    from scipy.optimize import least_squares

    from vdp import channels as ch
    from vdp.sim.independent.common import AUX

    tr = _trace(case, cache)
    truth, veh = _truth(case, cache)
    m, L, l_f = veh.mass, veh.wheelbase, truth["parameters"]["l_f"]
    sel = slice(int(T_STAGE2 * 1000), None, STEP)
    d, v_x = tr.values[sel, ch.DELTA], tr.aux[sel, AUX.index("v_x")]
    yaw, a_y = tr.values[sel, ch.YAW], tr.values[sel, ch.AY]
    skip = int(3000 / STEP)  # the model starts from rest: its first 3 s are left out
    t0 = np.array([truth["per_axle"]["C_alpha_front"], truth["per_axle"]["C_alpha_rear"], truth["parameters"]["I_z"]])

    def res(k):
        y, a = single_track(k * t0, d, v_x, STEP / 1000.0, m, L, l_f)
        return np.concatenate([(y - yaw)[skip:] / 0.01, (a - a_y)[skip:] / 0.1])

    def rms(e):
        n = len(e) // 2
        return math.sqrt(np.mean((e[:n] * 0.01) ** 2)), math.sqrt(np.mean((e[n:] * 0.1) ** 2))

    at_truth = rms(res(np.ones(3)))
    best = least_squares(res, np.ones(3), diff_step=1e-3)
    k, r = best.x, rms(best.fun)
    return (
        f"| `{case}` | {at_truth[0]:.4f} / {at_truth[1]:.3f} | {k[0]:.3f} | {k[1]:.3f} | {k[2]:.3f} "
        f"| {r[0]:.4f} / {r[1]:.3f} |"
    )


# -- terms: the single track with the models' left-out physics added back, term by term --
TERMS = ("curve", "load", "fiala", "mu", "roll", "mh", "swing", "rollcam", "rate", "camber", "fx", "kin", "arm")
DEFAULT_GROUPS = (
    "base,curve,roll,curve+roll,load+roll,load+roll+fx,load+roll+fx+kin,camber,camber+kin,"
    "load+camber+roll+fx+kin,load+camber+roll+fx+kin+arm,base+ay<1.5"
)


class _Tap:
    """Records the tyre-law calls of a model's first Runge-Kutta stage (the state the sample is taken at)."""

    def __init__(self, model):
        self.on, self.calls = False, []
        if model.name == "brush":
            import vdp.sim.independent.brush as mod

            names = ("brush_force",)
        else:
            import vehiclemodels.utils.tire_model as mod

            names = ("formula_lateral_comb", "formula_longitudinal_comb")
        self.mod, self.saved = mod, {n: getattr(mod, n) for n in names}
        for n, f in self.saved.items():
            setattr(mod, n, self._wrap(n, f))

    def _wrap(self, name, f):
        def tapped(*args):
            out = f(*args)
            if self.on:
                self.calls.append((name, args, out))
            return out

        return tapped

    def close(self):
        for n, f in self.saved.items():
            setattr(self.mod, n, f)


def record(case: str, cache: Path) -> dict:
    """The ``stage2`` scenario driven with every tyre's load, slips and forces recorded every STEP ms."""
    from independent import _source_hash
    from vdp.sim.driver import Driver, DriverConfig
    from vdp.sim.independent import get_model
    from vdp.sim.independent.common import DT, SETTLE
    from vdp.sim.scenario import get_scenario

    path = cache / f"{case.replace('/', '-')}-stage2-wheels-{STEP}ms-{_source_hash()}.npz"
    if path.exists():
        with np.load(path) as z:
            return {k: z[k] for k in z.files}
    name, car = case.split("/")
    model = get_model(name, car)
    sc = get_scenario("stage2", model.wheelbase)
    drv = Driver(DriverConfig(), model.mass, model.wheel_radius, model.wheel_inertia_axle)
    x, v_x = model.initial(sc.v0), sc.v0
    for _ in range(int(round(SETTLE / DT))):
        tf, tr, d = drv.update(DT, sc.v0, 0.0, 0.0, v_x)
        x, row = model.step(x, tf, tr, d, DT)
        v_x = row[14]
    tap, rows, states, wheels = _Tap(model), [], [], []
    hint = 0
    try:
        for n in range(int(round(sc.duration / DT))):
            v_cmd, a_cmd, d_cmd, hint = sc.command(n * DT, hint)
            tf, tr, d = drv.update(DT, v_cmd, a_cmd, d_cmd, v_x)
            keep = n % STEP == 0
            tap.on, tap.calls = keep, []
            x0 = list(x)
            x, row = model.step(x, tf, tr, d, DT)
            tap.on = False
            v_x = row[14]
            if keep:
                rows.append(row)
                states.append(x0)
                wheels.append(_wheels(model, tap.calls, x0))
    finally:
        tap.close()
    out = {"rows": np.array(rows), "states": np.array(states), "wheels": np.array(wheels)}
    np.savez_compressed(path, **out)
    return out


def _wheels(model, calls, x) -> list[list[float]]:
    """Per wheel (vdp's fl, fr, rl, rr): F_z, alpha, kappa, gamma, F_x, F_y, F_y at zero camber (vdp's signs)."""
    if model.name == "brush":
        out = []
        for args, (fx, fy) in ((c[1], c[2]) for c in calls[:4]):
            kappa, alpha, fz = args[0], args[1], args[2]
            out.append([fz, alpha, kappa, 0.0, fx, fy, fy])
        return out
    t, p = model._tire, model.p
    lat = [c for c in calls if c[0] == "formula_lateral_comb"][:4]
    lon = [c for c in calls if c[0] == "formula_longitudinal_comb"][:4]
    out = []
    for (_, a, fy), (_, _, fx) in zip(lat, lon):
        s, alpha, gamma, _, fz, _ = a[:6]
        f0, mu = t.formula_lateral(alpha, 0.0, fz, p.tire)
        fy0 = t.formula_lateral_comb(s, alpha, 0.0, mu, fz, f0, p.tire)
        out.append([fz, -alpha, -s, gamma, fx, fy, fy0])
    # the library's L wheels sit at y = -T/2 (vdp's right): fl <- its RF, fr <- its LF (mb.py)
    return [out[1], out[0], out[3], out[2]]


def _known(case: str, rec: dict, terms: set, lever: float, truth_h: float = 0.0):
    """Per-sample known inputs of the single track: extra lateral force, yaw moment, slip offsets, axle loads."""
    from vdp import channels as ch
    from vdp.sim.independent import get_model

    model = get_model(*case.split("/"))
    rows, X, W = rec["rows"], rec["states"], rec["wheels"]
    n, dt = len(rows), STEP / 1000.0
    d = rows[:, ch.DELTA]
    sd, cd = np.sin(d), np.cos(d)
    e_y, e_z = np.zeros(n), np.zeros(n)
    L = model.wheelbase
    l_r = L - lever
    if model.name == "brush":
        c = model.c
        ys = (0.5 * c.t_f, -0.5 * c.t_f, 0.5 * c.t_r, -0.5 * c.t_r)
        v_y, yaw, v_x = X[:, 1], X[:, 2], X[:, 0]
        if "roll" in terms:
            e_y += c.m_s * model.d * np.gradient(X[:, 4], dt)  # m a_y = sum F_y + m_s d phi''
    else:
        p = model.p
        ys = (0.5 * p.T_f, -0.5 * p.T_f, 0.5 * p.T_r, -0.5 * p.T_r)
        v_y, yaw, v_x = X[:, 10], X[:, 5], X[:, 3]
        if "roll" in terms:
            # the unsprung masses' sideways motion relative to the sprung mass (the joints' states 27, 28)
            e_y += p.m_uf * np.gradient(np.gradient(X[:, 27], dt), dt)
            e_y += p.m_ur * np.gradient(np.gradient(X[:, 28], dt), dt)
        if "arm" in terms:
            e_y -= (p.m_uf * p.a - p.m_ur * p.b) * np.gradient(yaw, dt)
    if "mh" in terms:
        # what the estimator could add with what it has: eq 9's whole mass and stage 1's h as the arm
        e_y += model.mass * truth_h * np.gradient(rows[:, ch.ROLL], dt)
    if "camber" in terms:
        cf, cr = (W[:, 0:2, 5] - W[:, 0:2, 6]).sum(1), (W[:, 2:4, 5] - W[:, 2:4, 6]).sum(1)
        e_y += cf * cd + cr
        e_z += lever * cf * cd - l_r * cr
    if "fx" in terms:
        fxf = W[:, 0:2, 4].sum(1)
        e_y += fxf * sd
        e_z += lever * fxf * sd
        for i in range(4):
            fx_body = W[:, i, 4] * cd - W[:, i, 5] * sd if i < 2 else W[:, i, 4]
            e_z -= ys[i] * fx_body
    da = np.zeros((n, 4))  # each wheel's recorded slip angle minus its axle's single-track one
    if "kin" in terms:
        v = np.maximum(v_x, 1.0)
        da[:, 0:2] = W[:, 0:2, 1] - (d - (v_y + lever * yaw) / v)[:, None]
        da[:, 2:4] = W[:, 2:4, 1] - ((l_r * yaw - v_y) / v)[:, None]
    return model, e_y, e_z, da, W[:, :, 0]


def _law(model, case, terms, truth, loads, da):
    """The axles' lateral laws (alpha, sample) -> force / truth's C, or None for the linear law.

    With ``load`` each wheel takes its own load and its own slip angle (the axle's single-track
    alpha plus the wheel's recorded offset ``da``, zero without ``kin``): the outer wheel of a
    turn carries more load at a slightly different slip angle (track width).
    """
    if not ({"curve", "load"} & terms):
        return None
    pa = truth["per_axle"]
    c0 = (pa["C_alpha_front"], pa["C_alpha_rear"])
    mean = (pa["F_z_front_stage2"], pa["F_z_rear_stage2"])
    axles = ("front", "rear")
    if "load" in terms and model.name == "brush":

        def law(j, a, i):
            w, o = loads[i, 2 * j : 2 * j + 2], da[i, 2 * j : 2 * j + 2]
            f = model.fy(a + o[0], max(w[0], 0.0), axles[j]) + model.fy(a + o[1], max(w[1], 0.0), axles[j])
            return f / c0[j]

        return law
    grid = np.linspace(-0.25, 0.25, 5001)
    tab = [np.array([2.0 * model.fy(a, mean[j] / 2.0, axles[j]) for a in grid]) / c0[j] for j in range(2)]
    if "load" not in terms:

        def law(j, a, i):
            return float(np.interp(a, grid, tab[j]))

        return law

    # the Magic Formula's force is proportional to the load (K_y = p_ky1 F_z, D = mu F_z): a wheel at
    # load F_z gives F_z / (axle's mean load) of the axle's curve at its own slip angle
    def law(j, a, i):
        w, o = loads[i, 2 * j : 2 * j + 2], da[i, 2 * j : 2 * j + 2]
        f = w[0] * float(np.interp(a + o[0], grid, tab[j])) + w[1] * float(np.interp(a + o[1], grid, tab[j]))
        return f / mean[j]

    return law


def _fiala(c: float, alpha: float, fz: float, mu: float = 1.0) -> float:
    """Fiala's (the isotropic brush's) lateral law of one axle: initial slope c, friction mu F_z."""
    t = c * abs(math.tan(alpha)) / (3.0 * mu * fz)
    f = mu * fz * (3.0 * t - 3.0 * t * t + t**3) if t < 1.0 else mu * fz
    return math.copysign(f, alpha)


def terms_fit(case: str, cache: Path, group: str) -> str:
    from scipy.optimize import least_squares

    from vdp import channels as ch

    terms = set(group.split("+")) - {"base"}
    max_ay = None
    for t in list(terms):
        if t.startswith("ay<"):
            max_ay = float(t[3:])
            terms.discard(t)
    unknown = terms - set(TERMS)
    if unknown:
        raise SystemExit(f"unknown term(s) {', '.join(sorted(unknown))}; choose from {', '.join(TERMS)} or ay<X")
    rec = record(case, cache)
    truth, veh = _truth(case, cache)
    m, L = veh.mass, veh.wheelbase
    lever = truth["parameters"]["l_f"]
    if "arm" in terms and case.startswith("mb/"):
        from vdp.sim.independent import get_model

        lever = get_model(*case.split("/")).p.a
    model, e_y, e_z, da, loads = _known(case, rec, terms, lever, truth["parameters"]["h"])
    law = _law(model, case, terms, truth, loads, da)
    per_wheel = law is not None and "load" in terms  # the law takes each wheel's own slip angle
    fiala = "fiala" in terms or "mu" in terms
    extras = [n for n in ("mu", "rollcam", "rate", "swing") if n in terms]  # fitted beside C_f, C_r, I_z
    x0 = np.array([1.0, 1.0, 1.0] + [{"mu": 1.0, "rollcam": 0.0, "rate": 0.0, "swing": 0.0}[n] for n in extras])
    p_rate = rec["rows"][:, ch.ROLL]
    phi_dd = np.gradient(rec["rows"][:, ch.ROLL], STEP / 1000.0)
    phi = np.cumsum(rec["rows"][:, ch.ROLL]) * (STEP / 1000.0)
    fz_f, fz_r = truth["per_axle"]["F_z_front_stage2"], truth["per_axle"]["F_z_rear_stage2"]
    rows = rec["rows"]
    d, v_x = rows[:, ch.DELTA], rows[:, 14]
    yaw_m, ay_m = rows[:, ch.YAW], rows[:, ch.AY]
    pa = truth["per_axle"]
    t0 = np.array([pa["C_alpha_front"], pa["C_alpha_rear"], truth["parameters"]["I_z"]])
    dt = STEP / 1000.0
    keep = np.arange(len(d)) >= int(3000 / STEP)  # the fit starts from rest
    if max_ay is not None:
        keep &= np.abs(ay_m) < max_ay

    def simulate(k):
        # Heun's method over the 5 ms samples, each rate evaluated with its own sample's inputs (the
        # original fit's explicit Euler step puts about 2 % into C and I_z by itself on brush/saloon)
        c_f, c_r, i_z = k[:3] * t0
        mu = k[3] if "mu" in extras else 1.0
        arm = k[-1] if "swing" in extras else 0.0
        cam = k[3 + extras.index("rollcam")] * 9.81 if "rollcam" in extras else 0.0
        q = k[3 + extras.index("rate")] if "rate" in extras else 0.0
        l_f, l_r = lever, L - lever

        def rates(v_y, r, i):
            v, cdi = v_x[i], math.cos(d[i])
            a_f = d[i] - (v_y + l_f * r) / v
            a_r = (l_r * r - v_y) / v
            if q:
                a_f += q * p_rate[i] / v
                a_r += q * p_rate[i] / v
            if not per_wheel:
                a_f += 0.5 * (da[i, 0] + da[i, 1])
                a_r += 0.5 * (da[i, 2] + da[i, 3])
            if fiala:
                f_yf, f_yr = _fiala(c_f, a_f, fz_f, mu), _fiala(c_r, a_r, fz_r, mu)
            elif law is None:
                f_yf, f_yr = c_f * a_f, c_r * a_r
            else:
                f_yf, f_yr = c_f * law(0, a_f, i), c_r * law(1, a_r, i)
            ay = (f_yf * cdi + f_yr + e_y[i]) / m + arm * phi_dd[i] + cam * phi[i]
            return ay - v * r, (l_f * f_yf * cdi - l_r * f_yr + e_z[i]) / i_z, ay

        n = len(d)
        v_y = r = 0.0
        yaw, a_y = np.empty(n), np.empty(n)
        for i in range(n):
            dv, dr, ay = rates(v_y, r, i)
            yaw[i], a_y[i] = r, ay
            if i + 1 < n:
                dv2, dr2, _ = rates(v_y + dt * dv, r + dt * dr, i + 1)
                v_y += 0.5 * dt * (dv + dv2)
                r += 0.5 * dt * (dr + dr2)
        return yaw, a_y

    def res(k):
        y, a = simulate(k)
        return np.concatenate([(y - yaw_m)[keep] / 0.01, (a - ay_m)[keep] / 0.1])

    def rms(e):
        h = len(e) // 2
        return math.sqrt(np.mean((e[:h] * 0.01) ** 2)), math.sqrt(np.mean((e[h:] * 0.1) ** 2))

    at_truth = rms(res(x0))
    lo = [0.05, 0.05, 0.05] + [{"mu": 0.2, "rollcam": -5.0, "rate": -2.0, "swing": -2.0}[n] for n in extras]
    hi = [20.0, 20.0, 20.0] + [{"mu": 5.0, "rollcam": 5.0, "rate": 2.0, "swing": 2.0}[n] for n in extras]
    best = least_squares(res, x0, bounds=(lo, hi), diff_step=1e-3)
    k, r = best.x, rms(best.fun)
    for j, n in enumerate(extras):
        group += f" ({n} {k[3 + j]:.3g}{' m' if n in ('swing', 'rate') else ''})"
    return (
        f"| `{case}` | {group} | {at_truth[0]:.4f} / {at_truth[1]:.3f} | {k[0]:.3f} | {k[1]:.3f} | {k[2]:.3f} "
        f"| {r[0]:.4f} / {r[1]:.3f} |"
    )


def secant(case: str, cache: Path) -> list[str]:
    """Each axle's effective (secant) cornering stiffness in a steady turn, as a multiple of the truth's.

    At a_y the axle must carry m a_y l_r / L (front) or m a_y l_f / L (rear).  The slip angle
    that gives it is found on the model's own tyre law twice: with both wheels at the
    axle's mean load (curvature alone), and with each wheel at its load in the turn (the
    lateral load transfer per m/s^2 taken from the recorded stage-2 drive by least
    squares on a_y, so the model's own roll and roll centres set it).  The ratio of the
    force to C_truth alpha is what a linear law fitted at that a_y would read.
    """
    from scipy.optimize import brentq

    from vdp import channels as ch
    from vdp.sim.independent import get_model

    model = get_model(*case.split("/"))
    truth, veh = _truth(case, cache)
    rec = record(case, cache)
    ay_rec, W = rec["rows"][:, ch.AY], rec["wheels"]
    pa = truth["per_axle"]
    l_f = truth["parameters"]["l_f"]
    out = []
    for j, axle in enumerate(("front", "rear")):
        c0, z = pa[f"C_alpha_{axle}"], pa[f"F_z_{axle}_stage2"]
        # left-wheel load minus the axle's mean half load, per m/s^2 (the right wheel takes the opposite)
        dz = W[:, 2 * j, 0] - W[:, 2 * j : 2 * j + 2, 0].mean(1)
        k = float(np.dot(dz, ay_rec) / np.dot(ay_rec, ay_rec))
        cells = []
        for a_y in (1.0, 2.0, 3.0):
            force = veh.mass * a_y * ((veh.wheelbase - l_f) if j == 0 else l_f) / veh.wheelbase
            half = z / 2.0

            def mean_load(a, half=half, axle=axle):
                return 2.0 * model.fy(a, half, axle)

            def turn(a, half=half, a_y=a_y, k=k, axle=axle):
                return model.fy(a, half + k * a_y, axle) + model.fy(a, half - k * a_y, axle)

            row = []
            for law in (mean_load, turn):
                a = brentq(lambda x, law=law, f=force: law(x) - f, 0.0, 0.3)
                row.append(force / (c0 * a))
            cells.append(f"{row[0]:.3f} / {row[1]:.3f}")
        out.append(f"| `{case}` | {axle} | {k:+.0f} | " + " | ".join(cells) + " |")
    return out


def replay_one(case: str, cache: Path, pin: bool, no_roll: bool, per_axle: bool, no_fxf: bool = False) -> list[str]:
    import logging

    from vdp.core.estimator import EstimatorConfig
    from vdp.core.learner import LearnerConfig, Stage2
    from vdp.io.logs import open_log
    from vdp.pipeline import Pipeline
    from vdp.replay import replay
    from vdp.sim.independent.common import IndependentSimulation
    from vdp.sim.run import write_log

    logging.getLogger("vdp").setLevel(logging.ERROR)
    model, car = case.split("/")
    sim = IndependentSimulation(model, car, "paper", seed=0, noise="none", trace=_trace(case, cache))
    t = sim.truth["parameters"]
    set_stage1, measurements = Stage2.set_stage1, Stage2.measurements
    if pin or no_fxf:

        def pinned(self, l_f, h, c_k, l_f_std=None, *rest):
            if pin:
                l_f, h, c_k, l_f_std = t["l_f"], t["h"], t["C_K"], 1e-4
            set_stage1(self, l_f, h, None if no_fxf else c_k, l_f_std)

        Stage2.set_stage1 = pinned
    if no_roll:

        def without_roll(s):
            z, mask = measurements(s)
            mask = mask.copy()
            mask[1] = False  # lateral.Z_ROLL
            return z, mask

        Stage2.measurements = staticmethod(without_roll)
    try:
        with tempfile.TemporaryDirectory() as tmp:
            log = Path(tmp) / "drive.log"
            write_log(sim.frames(), log, sim.bus_channel)
            pipe = Pipeline(sim.profile, EstimatorConfig(learner=LearnerConfig(per_axle=per_axle)))
            res = replay(open_log(log, channel=sim.profile.bus_channel), pipe).to_dict()
    finally:
        Stage2.set_stage1, Stage2.measurements = set_stage1, staticmethod(measurements)
    out = []
    for kind, key in (("UKF", "parameters"), ("EKF", "baseline_ekf")):
        p = res.get(key) or {}
        if not p:
            continue
        cells = [f"{100 * (p[n]['value'] / t[n] - 1):+.1f} %" for n in ("C_alpha", "I_z", "I_x")]
        out.append(f"| `{case}` | {kind} | " + " | ".join(cells) + " |")
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("what", choices=("fit", "replay", "terms", "secant"))
    ap.add_argument("--terms", default=DEFAULT_GROUPS, help="groups of terms for 'terms' (see the module doc)")
    ap.add_argument("--cases", default=",".join(CASES))
    ap.add_argument("--pin", action="store_true", help="stage 2 gets the truth's l_f, h, C_K")
    ap.add_argument("--no-roll", action="store_true", help="stage 2 leaves the roll-rate row out")
    ap.add_argument("--no-fxf", action="store_true", help="stage 2 leaves the front longitudinal force out")
    ap.add_argument("--per-axle", action="store_true")
    ap.add_argument("--cache", type=Path, default=Path(tempfile.gettempdir()) / "vdp-independent-traces")
    a = ap.parse_args()
    a.cache.mkdir(parents=True, exist_ok=True)
    cases = [c for c in a.cases.split(",") if c]
    if a.what == "fit":
        print("| model | rms yaw / a_y error at the truth | C_f | C_r | I_z (best fit / truth) | rms at the best fit |")
        print("|---|---|---|---|---|---|")
        for c in cases:
            print(fit(c, a.cache))
        return 0
    if a.what == "secant":
        print("| model | axle | lateral transfer per wheel [N per m/s^2] | a_y 1 m/s^2 | 2 m/s^2 | 3 m/s^2 |")
        print("|---|---|---|---|---|---|")
        for c in cases:
            print("\n".join(secant(c, a.cache)), flush=True)
        return 0
    if a.what == "terms":
        print("| model | terms added | rms yaw / a_y at the truth | C_f | C_r | I_z (best fit / truth) | rms at best |")
        print("|---|---|---|---|---|---|---|")
        for c in cases:
            for g in a.terms.split(","):
                print(terms_fit(c, a.cache, g), flush=True)
        return 0
    # the replay runs with the EKF baseline too (EstimatorConfig's default)
    print("| model | filter | C_alpha | I_z | I_x |")
    print("|---|---|---|---|---|")
    for c in cases:
        print("\n".join(replay_one(c, a.cache, a.pin, a.no_roll, a.per_axle, a.no_fxf)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
