"""How far learning has got, and what to drive next: from what the learners have, never a timer.

Pure: a snapshot (the estimator's parameters, supervisor state and capabilities) and the
priors in, numbers and words out.

- **Information gained** is the share of the way the std has come from the prior's to the
  convergence threshold, on a log scale: ``ln(prior/std) / ln(prior/target)``, with
  ``target = converged_rel * |value|`` (the learners' own convergence rule).  1 only when
  the learner says ``converged``.
- **Time still needed**: while the data, not the prior, sets the std, it shrinks as
  1/sqrt(samples), so reaching the target takes ``window_s * ((std/target)^2 - 1)`` more
  seconds of the same driving (an estimate from the learner's state, shown as such).
- **The hint** follows the supervisor's reason for its stage's gate (excitation seen, speed,
  steering, a missing channel) in words a driver can act on.
"""

from __future__ import annotations

import math

from .params import BY_NAME, NAMES, STAGE1, STAGE2
from .result import CONVERGED, INVALID, NOT_IDENTIFIABLE, NOT_RUN, UNCERTAIN
from .supervisor import Code, Reason

STAGE_PARAMS = {1: STAGE1, 2: STAGE2}

# What each stage needs, said to a driver (Table 2 of the paper, and the supervisor's gates).
DRIVE = {
    1: "on a straight, level road, accelerate firmly and brake, again and again "
    "(say 40 to 90 km/h and back every 10 s or so), keeping the wheel straight",
    2: "at a steady 30 to 50 km/h on a wide, empty road or lot, weave: swing the steering wheel "
    "left and right continuously (about a quarter turn each way), one swing every 3 to 10 s",
}

# The supervisor's reasons (core.supervisor.Reason, by code) turned into what to change.
_FIX = {
    Code.SPEED_LOW: "too slow: it needs more than 20 km/h",
    Code.STEERING: "the wheel is turned: hold it straight",
    Code.YAWING: "the car is turning: find a straight stretch",
    Code.LITTLE_AX: "the speed is not changing enough",
    Code.LITTLE_STEER: "not enough steering yet",
    Code.NOT_CONSTANT: "the speed is changing: hold it steady (cruise control helps)",
}
# core.gates: reverse, ABS, ESC, TCS, a kerb strike, wheel spin
_FIX.update(
    dict.fromkeys(
        (Code.GATED_REVERSE, Code.GATED_ABS, Code.GATED_ESC, Code.GATED_TCS, Code.GATED_KERB, Code.GATED_SPIN),
        "outside the model (reversing, ABS, ESC, traction control, a kerb or a spinning wheel): "
        "it waits until the car drives forwards on all four tyres again",
    )
)

# Per parameter, what excites it most (where it differs from its stage's manoeuvre).
_EXTRA = {
    "h": "firm braking moves most load between the axles, which is what shows the CG height",
    "I_x": "roll needs quick steering reversals: weave faster, about one swing per second",
    "I_z": "quick steering reversals show the yaw inertia best",
}


def _fix(reason: Reason | str | None) -> str | None:
    """What to change for a supervisor's reason (None for "open", the hand-over and the like)."""
    code = getattr(reason, "code", None)
    if code == Code.MISSING:
        return f"check the bus: {', '.join(reason.channels)} silent or stale"
    return _FIX.get(code)


def information(value: float | None, std: float | None, prior_std: float, converged_rel: float) -> float:
    """0 at the prior's std, 1 at the convergence threshold (log scale), clipped to [0, 1]."""
    if value is None or std is None or not (std > 0 and prior_std > 0 and math.isfinite(value)):
        return 0.0
    target = converged_rel * abs(value)
    if target <= 0:
        return 0.0
    if target >= prior_std:  # the prior alone is already tight enough: any data finishes it
        return 1.0 if std <= target else 0.0
    f = math.log(prior_std / std) / math.log(prior_std / target)
    return min(max(f, 0.0), 1.0)


def seconds_to_go(value: float | None, std: float | None, window_s: float, converged_rel: float) -> float | None:
    """More seconds of the same driving until std reaches the threshold, if the data keeps coming
    as it has (std ~ 1/sqrt(samples)); None before any window."""
    if value is None or std is None or window_s <= 0 or not math.isfinite(value):
        return None
    target = converged_rel * abs(value)
    if target <= 0 or std <= target:
        return 0.0
    return window_s * ((std / target) ** 2 - 1.0)


def _duration(s: float) -> str:
    if s < 90:
        return f"{max(s, 1):.0f} s"
    if s < 3600:
        return f"{s / 60:.0f} min"
    return "more than an hour"


def assess(snapshot: dict, priors: dict, tick: float) -> dict:
    """Per parameter progress (0-1) and a hint, per stage progress and the next manoeuvre.

    ``snapshot``: the estimator's (``parameters``, ``stage``, ``supervisor``, ``capabilities``);
    ``priors``: name -> object with ``std`` (the profile's); ``tick``: s per sample.
    """
    params = snapshot.get("parameters") or {}
    sup = snapshot.get("supervisor") or {}
    reasons = sup.get("reasons") or {}
    excitation = sup.get("excitation") or {}
    caps = snapshot.get("capabilities") or {}
    # stage 2 waits on stage 1 while the supervisor says so (what it waits for is its to say)
    gate2 = reasons.get("2")
    handed_over = snapshot.get("stage") in ("stage2", "done") or not (
        not gate2 or getattr(gate2, "code", None) in (Code.WAITING, Code.NO_DATA)
    )

    # what the UKF learners say they have seen (est's supervisor.learners), when given
    seen = (sup.get("learners") or {}).get("ukf") or {}
    hard = _too_hard(seen.get("stage1") or {})

    out: dict = {"parameters": {}, "stages": {}}
    for name in NAMES:
        spec, p = BY_NAME[name], params.get(name) or {}
        stage = spec.stage
        status = p.get("status", NOT_RUN)
        learner = seen.get(f"stage{stage}") or {}
        window_s = learner.get("seconds_in_windows")
        if window_s is None:
            window_s = (p.get("samples") or 0) * tick
        info = information(p.get("value"), p.get("std"), priors[name].std, spec.converged_rel)
        flagged = p.get("reason") is not None and not p.get("valid", status == CONVERGED)
        # a flagged estimate (say, "model mismatch: ...") is not learnt, however small its std
        progress = 1.0 if status == CONVERGED and not flagged else min(info, 0.99) if status != INVALID else 0.0
        to_go = seconds_to_go(p.get("value"), p.get("std"), window_s, spec.converged_rel)
        out["parameters"][name] = {
            "progress": round(progress, 3),
            "information": round(info, 3),
            "window_s": round(window_s, 2),
            "seconds_to_go": None if to_go is None or status != UNCERTAIN else round(to_go, 1),
            "hint": _hint(
                name,
                stage,
                status,
                p,
                to_go,
                priors[name].std,
                caps.get(str(stage)) or caps.get(name),  # a stage, or one parameter (I_x: no roll rate)
                reasons,
                excitation,
                handed_over,
            ),
        }
        if stage == 1 and hard and status in (UNCERTAIN, NOT_IDENTIFIABLE):
            out["parameters"][name]["hint"] += f"; {hard}"
    for stage, names in STAGE_PARAMS.items():
        per = out["parameters"]
        # the mean over the stage's parameters this car can learn (I_x without a roll-rate gyro is
        # not one: counted as done, it had shown a stage that never ran at 33 %); one the data was
        # judged unable to pin no longer holds its stage back (the estimator calls the stage done
        # then, too), nor one whose model cannot explain the data ("model mismatch: ...": more of
        # the same driving will not fix it, its hint says)
        counted = [
            1.0
            if params.get(n, {}).get("status") == NOT_IDENTIFIABLE or _mismatch(params.get(n) or {})
            else per[n]["progress"]
            for n in names
            if not caps.get(n)
        ]
        ex = excitation.get(str(stage)) or {}
        out["stages"][str(stage)] = {
            "progress": round(sum(counted) / len(counted), 3) if counted else 1.0,
            "can_run": not caps.get(str(stage)),
            "why_not": caps.get(str(stage)),
            "gate": reasons.get(str(stage)),
            "excited_s": ex.get("seconds"),
            "observed_s": ex.get("of"),
            "window_s": (seen.get(f"stage{stage}") or {}).get("seconds_in_windows"),
        }
    s1 = seen.get("stage1") or {}
    if "blocks_used" in s1:
        out["stages"]["1"]["blocks_used"] = s1["blocks_used"]
        out["stages"]["1"]["blocks_beyond_small_slip"] = s1.get("blocks_beyond_small_slip")
    out["next"] = _next(snapshot, out, reasons, caps)
    return out


def _mismatch(p: dict) -> bool:
    """Flagged not valid because the model cannot explain the data (driving more will not help)."""
    return "mismatch" in (p.get("reason") or "") and not p.get("valid", False) and p.get("status") != INVALID


def _too_hard(stage1: dict) -> str | None:
    """Stage 1 leaves out blocks beyond the tyres' small-slip range (C_K is the small-slip
    stiffness): when most of the driving is, the driver should ease off, not push harder."""
    used, beyond = stage1.get("blocks_used") or 0, stage1.get("blocks_beyond_small_slip") or 0
    if used + beyond < 20 or beyond < used:
        return None
    share = 100 * beyond / (used + beyond)
    return f"ease off a little: {share:.0f} % of the acceleration and braking so far was too hard to use"


def _hint(name, stage, status, p, to_go, prior_std, why_not, reasons, excitation, handed_over) -> str:
    if why_not:
        # a message the bus never carried may be the log's (another bus channel, a short log), not the car's
        where = "from this bus" if "never carried" in why_not else "on this car"
        return f"cannot be learnt {where}: {why_not}"
    if p.get("reason") is not None and not p.get("valid", status == CONVERGED) and status != INVALID:
        if "mismatch" not in p["reason"]:
            # e.g. I_x's "roll not excited: ...": other driving can fix it, and its reason says which
            return f"not valid: {p['reason']}"
        return f"not valid: {p['reason']}; more of the same driving will not fix it, the car differs from the model"
    if status == CONVERGED:
        rel = (p.get("std") or 0) / abs(p["value"]) if p.get("value") else 0
        return f"enough: known to ±{100 * rel:.1f} % (1σ); nothing more to drive for it"
    if status == INVALID:
        return "the estimate left its sane range; it restarts from its last good value — keep driving"
    if stage == 2 and not handed_over:
        why = str(reasons.get("2") or "waiting for stage 1")
        return f"{why}: first " + DRIVE[1]
    reason = reasons.get(str(stage))
    if status == NOT_IDENTIFIABLE:
        extra = _EXTRA.get(name)
        return (
            "this driving has not narrowed it (std still above half the prior's): "
            + (extra if extra else DRIVE[stage])
            + "; until then its value is mostly the prior's"
        )
    if reason == "open":
        # the 1/sqrt(samples) extrapolation holds once the data, not the prior, sets the std
        sure = to_go and information(p.get("value"), p.get("std"), prior_std, BY_NAME[name].converged_rel) > 0.5
        more = f" for about {_duration(to_go)} more" if sure else ""
        head = f"learning now: keep doing this{more}"
        return head + (f"; {_EXTRA[name]}" if name in _EXTRA else "")
    fix = _fix(reason)
    seen = (excitation.get(str(stage)) or {}).get("seconds")
    had = f" (the drive has given {seen:.0f} s of it so far)" if seen else ""
    return DRIVE[stage] + had + (f"; now: {fix}" if fix else "")


def _next(snapshot, out, reasons, caps) -> str:
    """The one manoeuvre to drive next, in a driver's words: the stage whose window is open now
    (never switch a driver mid-manoeuvre), else the one furthest behind (stage 1 on a tie)."""
    if caps.get("1") and caps.get("2"):
        return "nothing to drive: this car's bus lacks what both stages need (see the stages)"
    waits = snapshot.get("stage", "stage1") == "stage1"  # stage 2 waits for l_f
    todo = [
        n for n in (1, 2) if not caps.get(str(n)) and not (n == 2 and waits) and out["stages"][str(n)]["progress"] < 1.0
    ]
    if not todo:
        if waits and caps.get("1"):
            return (
                f"stage 1 cannot run on this car ({caps['1']}); stage 2 needs its l_f, or a measured l_f in the profile"
            )
        cannot = [f"stage {n} cannot run on this car: {caps[str(n)]}" for n in ("1", "2") if caps.get(n)]
        return "done: every parameter is learnt or known not to be learnable from driving; drive normally" + (
            f" ({'; '.join(cannot)})" if cannot else ""
        )
    open_now = [n for n in todo if reasons.get(str(n)) == "open"]
    if open_now:
        return f"keep going: {DRIVE[open_now[0]]}"
    n = min(todo, key=lambda k: (out["stages"][str(k)]["progress"], k))
    fix = _fix(reasons.get(str(n)))
    return DRIVE[n][0].upper() + DRIVE[n][1:] + (f" — now: {fix}" if fix else "")
