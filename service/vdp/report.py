"""Replay results as JSON, a terminal table and a plot (in the spirit of the paper's Figs 5 and 7)."""

from __future__ import annotations

import json
import math
import textwrap
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from .core.params import BY_NAME, MASS, NAMES, PUBLISHED
from .core.result import NOT_RUN, Estimate
from .errors import ConfigError
from .outfile import replacing, write_text
from .result import RunResult, jsonable


def load_truth(path: str | Path) -> dict:
    p = Path(path)
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except FileNotFoundError:
        raise ConfigError(f"{p}: no such truth file") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise ConfigError(f"{p}: not a truth JSON file: {exc}") from None
    params = data.get("parameters")
    if not isinstance(params, dict):
        raise ConfigError(f"{p}: has no 'parameters' object; is it a .truth.json from vdp simulate?")
    return data


def compare(params: Mapping[str, Estimate], truth: dict) -> dict:
    """Relative error of each estimate, and whether truth is inside value +- 2 std."""
    out = {}
    for name in PUBLISHED:
        t = truth["parameters"].get(name)
        if name == MASS and t is None:
            t = truth.get("mass")  # the loaded car's (vdp simulate --load), beside the six
        e = params.get(name)
        v, sd = (e.value, e.std) if e is not None else (None, None)
        if t is None or v is None:
            out[name] = {"truth": t, "rel_error": None, "within_2std": None}
            continue
        out[name] = {"truth": t, "rel_error": (v - t) / t, "within_2std": bool(sd is not None and abs(v - t) <= 2 * sd)}
    return out


_DRIVE_WORDS = {1: "straight-line acceleration and braking", 2: "steady speed with continuous steering"}


def document(result: RunResult, truth: dict | None = None) -> dict[str, Any]:
    """The JSON document of a replay: the result, and the comparison with a truth file if given."""
    doc = result.to_dict()
    if truth is not None:
        doc["truth"] = truth["parameters"]
        doc["truth_comparison"] = compare(result.parameters, truth)
        if result.baseline_ekf:
            doc["truth_comparison_ekf"] = compare(result.baseline_ekf, truth)
    return doc


def stage_lines(result: RunResult) -> list[str]:
    """One line per stage that produced nothing: why it could not run, and what the drive offered."""
    lines = []
    exc = result.supervisor.get("excitation", {})
    for stage in ("1", "2"):
        ran = any(str(w.stage) == stage for w in result.windows)
        if ran:
            continue
        why = result.capabilities.get(stage)
        if why:
            lines.append(f"stage {stage} cannot run: {why}")
        e = exc.get(stage) or {}
        if e.get("of"):
            blocker = e.get("main_blocker")
            if e["seconds"] > 0 and not why:
                blocker = result.supervisor["reasons"].get(stage, blocker)
            lines.append(
                f"stage {stage}: the drive had {e['seconds']:.1f} of {e['of']:.1f} s of "
                f"{_DRIVE_WORDS[int(stage)]}"
                + (f"; mostly: {blocker}" if blocker else "")
                + (" (what the driving offered; the stage cannot use it, above)" if why else "")
            )
    why = result.capabilities.get("I_x")
    if why:
        lines.append(f"I_x cannot run: {why}")
    return lines


def gate_lines(result: RunResult) -> list[str]:
    """The share of the drive gated out (core.gates): "16 % of the drive gated out: reverse 4 %,
    ABS 3.1 %, ..."; nothing for a result without the gates' counts (one stored before them)."""
    g = result.supervisor.get("gated") or {}
    return [f"gates: {g['text']}"] if g.get("of") else []


# what to check when the decoder refuses frames of a message the profile maps
_DECODE_HINTS = {
    "dlc": "shorter than the DBC says; if the car sends them short, set [can] pad_short = true, "
    "or check that the frames are from the profile's bus ([can] channel)",
    "range": "values outside the DBC's range (a start-up sentinel, or the wrong signal layout)",
    "counter": "a rolling counter that skipped: lost frames, the same id from another bus (set [can] "
    "channel), or a counter signal that is not one",
    "checksum": "a failed checksum (damaged frames, or the wrong checksum kind in the profile)",
    "nonfinite": "values that are not numbers",
    "mux": "a multiplexer value the DBC does not hold",
    "remote": "remote frames, not data",
    "decode": "frames cantools could not decode with the DBC",
}


def decode_lines(result: RunResult) -> list[str]:
    """One line per kind of frame the decoder refused in the messages the profile maps, with what
    to check (the JSON's decode section has them by id): otherwise only there, and a profile
    that drops a tenth of its steering frames looked fine on the console."""
    d = result.decode or {}
    names = d.get("messages") or {}
    out = []
    for ident, kinds in sorted((d.get("errors") or {}).items()):
        for kind, n in sorted(kinds.items()):
            if n and kind in _DECODE_HINTS:
                what = f"{names[ident]} ({ident})" if ident in names else ident
                out.append(f"decoder: {n} frame(s) of {what} refused: {_DECODE_HINTS[kind]}")
    return out


def _unit(unit: str) -> str:
    """A unit as printed: "-" for a ratio (C_K's SI unit "1" read as a number)."""
    return "-" if unit == "1" else unit


def _fmt(v, digits=4):
    if v is None:
        return "-"
    if v == 0 or 1e-3 <= abs(v) < 1e5:
        return f"{v:.{digits}g}"
    return f"{v:.3e}"


def table(result: RunResult, truth: dict | None = None) -> str:
    """A fixed-width table of the six parameters and the mass (UKF), the EKF baseline where it ran
    and, if known, the truth."""
    params, ekf = result.parameters, result.baseline_ekf or {}
    has_ekf = bool(ekf)  # (a column of dashes when the baseline did not run only raised questions)
    cmp_ = compare(params, truth) if truth is not None else {}
    cmp_ekf = compare(ekf, truth) if truth is not None and ekf else {}
    # "valid": usable as it stands (learnt, in range, its std within the parameter's threshold); "!": a
    # reason follows the table (a valid value may have one: a finding beside it)
    head = f"{'param':8} {'value':>10} {'± std':>10} {'unit':7} {'valid':5} {'status':17}"
    head += f" {'EKF value':>10}" if has_ekf else ""
    if cmp_:
        head += f" {'truth':>10} {'UKF err':>8}" + (f" {'EKF err':>8}" if has_ekf else "")
    lines = [head, "-" * len(head)]
    names = [n for n in PUBLISHED if n in params]  # (a result made before the mass was published has none)
    for name in names:
        p = params[name]
        e = ekf.get(name)
        status = p.status + ("!" if p.reason else "")  # a reason follows the table
        ok = "yes" if p.valid else "no"
        row = f"{name:8} {_fmt(p.value):>10} {_fmt(p.std, 2):>10} {_unit(p.unit):7} {ok:5} {status:17}"
        row += f" {_fmt(e.value if e is not None else None):>10}" if has_ekf else ""
        if cmp_:
            c, ce = cmp_[name], cmp_ekf.get(name, {})
            err = "-" if c["rel_error"] is None else f"{100 * c['rel_error']:+.2f}%"
            err_e = "-" if ce.get("rel_error") is None else f"{100 * ce['rel_error']:+.2f}%"
            row += f" {_fmt(c['truth']):>10} {err:>8}" + (f" {err_e:>8}" if has_ekf else "")
        lines.append(row)
    # why each marked parameter is what it is (a profile-check mismatch, a model mismatch,
    # roll not excited, no roll-rate gyro, a measured l_f ...)
    lines += [f"! {n}: {params[n].reason}" for n in names if params[n].reason]
    lines += axle_lines(params, truth)
    lines += mass_lines(params)
    return "\n".join(lines)


def mass_lines(params: Mapping[str, Estimate]) -> list[str]:
    """The learnt mass's story in one line (its ``extra``, core.mass): when it first read valid, in
    the drive's time, and the IMU's pitch gain learnt beside it; none where it was not learnt."""
    e = params.get("mass")
    x = e.extra if e is not None else {}
    if not x or "driven_s" not in x or e.status == NOT_RUN:
        return []
    after, driven = x.get("valid_after_s"), (x["driven_s"] or 0.0) / 60.0
    part = [f"valid after {after / 60:.1f} of {driven:.1f} min of drive" if after is not None
            else f"not valid after {driven:.1f} min of drive"]  # fmt: skip
    if x.get("pitch_gain_kappa") is not None:
        rows = x.get("pitch_level_rows") or 0
        part.append(
            f"the IMU's pitch with the body reads {100 * x['pitch_gain_kappa']:.1f} % ± "
            f"{100 * (x.get('pitch_gain_std') or 0.0):.1f} % of a_x ({rows} level-road rows against the GNSS speed)"
            if rows
            else "the IMU's pitch gain is not learnt yet (it needs level road and a GNSS speed)"
        )
        k, ks = x["pitch_gain_kappa"], x.get("pitch_gain_std") or 0.0
        if rows and abs(k) > max(2.0 * ks, 0.01):
            # the six still read the tilted a_x and a_y: stage 1's load transfer, eq 9's a_y (core.road)
            part.append("the IMU tilts with the body: replay with --road to take that out of the six's a_x and a_y")
    return ["mass: " + "; ".join(part)]


def axle_lines(params: Mapping[str, Estimate], truth: dict | None = None) -> list[str]:
    """C_alpha per axle (its ``extra``, when stage 2 estimates each axle), one line, with the
    truth's per-axle values if known and why they are not valid."""
    e = params.get("C_alpha")
    x = e.extra if e is not None else {}
    if x.get("C_alpha_front") is None:
        return []
    line = (
        f"C_alpha per axle (C_alpha is their mean): front {_fmt(x['C_alpha_front'])} ± "
        f"{_fmt(x.get('C_alpha_front_std'), 2)}, rear {_fmt(x['C_alpha_rear'])} ± "
        f"{_fmt(x.get('C_alpha_rear_std'), 2)} N/rad"
    )
    per = (truth or {}).get("per_axle") or {}
    if "C_alpha_front" in per and "C_alpha_rear" in per:
        line += f" (truth {_fmt(per['C_alpha_front'])} / {_fmt(per['C_alpha_rear'])})"
    why = x.get("per_axle_reason")
    if not why:
        return [line]
    # (a reason beside axles that are valid is a finding, not a verdict)
    return [line, f"  {'valid; ' if x.get('per_axle_valid') else 'not valid: '}{why}"]


def write_json(doc: dict | RunResult, path: str | Path) -> None:
    """Strict JSON (never NaN: non-finite numbers become null)."""
    write_text(path, json.dumps(jsonable(doc), indent=2, allow_nan=False) + "\n")


# The paper's figures: Fig. 5 is stage 1 (C_K, h, l_f), Fig. 7 stage 2 (C_alpha, I_x, I_z);
# each panel is one parameter over time, the real value as a line, UKF and EKF.
FIGURE_PANELS = ((5, ("C_K", "h", "l_f")), (7, ("C_alpha", "I_x", "I_z")))
_WINDOW_COLOR = {1: "tab:green", 2: "tab:orange"}
_REPORTED = "tab:purple"  # the value and std the result reports, at the end of the trace
_SYMBOL = {"C_K": "$C_K$", "h": "$h$", "l_f": "$l_f$", "C_alpha": r"$C_\alpha$", "I_x": "$I_x$", "I_z": "$I_z$"}


def _wrap(text: str, width: int = 60) -> str:
    import textwrap

    return "\n".join(textwrap.wrap(text, width))


def _column(rows, col: int, i: int):
    import numpy as np

    val = np.array([np.nan if r[col][i][0] is None else r[col][i][0] for r in rows])
    sd = np.array([np.nan if r[col][i][1] is None else r[col][i][1] for r in rows])
    return val, sd


def _limits(val, sd, ref, prior_std):
    """y limits: the estimate's whole path (from the prior's value on, as in the paper's figures),
    the reference, and the ±2σ band only where the data has made it narrow (std below a quarter
    of the prior's); the wide early band is clipped rather than allowed to set the axes."""
    import numpy as np

    ok = np.isfinite(val)
    narrow = ok & np.isfinite(sd) & (sd < 0.25 * prior_std)
    pool = [val[ok], val[narrow] - 2 * sd[narrow], val[narrow] + 2 * sd[narrow]]
    if ref is not None:
        pool.append(np.array([ref]))
    flat = np.concatenate(pool)
    if not len(flat):
        return None
    lo, hi = float(flat.min()), float(flat.max())
    pad = max(0.12 * (hi - lo), 0.01 * max(abs(hi), abs(lo)) + 1e-12)
    return lo - pad, hi + pad


def plot(
    trace,
    windows,
    path: str | Path,
    truth: dict | None = None,
    title: str = "",
    params: dict | None = None,
    priors: dict | None = None,
    capabilities: dict | None = None,
) -> None:
    """Write :func:`figure` to ``path`` (PNG, PDF or SVG by suffix)."""
    import matplotlib.pyplot as plt

    fig = figure(trace, windows, truth, title, params, priors, capabilities)
    try:
        with replacing(path) as tmp:
            fig.savefig(tmp, dpi=110)
    finally:
        plt.close(fig)


def figure(
    trace,
    windows,
    truth: dict | None = None,
    title: str = "",
    params: dict | None = None,
    priors: dict | None = None,
    capabilities: dict | None = None,
):
    """The paper's Figures 5 and 7 side by side: per parameter, the real value (when a truth or
    reference file gives it), the UKF with its ±2σ band and the EKF baseline over time, the
    gating windows shaded, the prior marked where it falls.

    ``trace`` rows are (t, stage, UKF ((value, std) per parameter), [EKF ...]) in NAMES order;
    ``params`` (the result's UKF parameters) puts each final value and status in its panel;
    ``priors`` (name -> object with value, std) marks the prior; ``capabilities`` (per stage
    "1"/"2": why it cannot run on this car, or None) explains an empty column.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    rows = list(trace)
    ref_all = (truth or {}).get("parameters", {})
    fig, axes = plt.subplots(3, 2, figsize=(12, 10), sharex="col")
    t = np.array([r[0] for r in rows]) if rows else np.array([0.0])
    t_end = float(t[-1]) if rows else 1.0
    has_ekf = bool(rows) and len(rows[0]) > 3
    marked = False  # a reported value was drawn in some panel (its legend entry)
    for c, (fig_no, names) in enumerate(FIGURE_PANELS):
        stage = c + 1
        starts = [w["start"] for w in windows if w["stage"] == stage]
        # stage 2 runs after the hand-over: its column starts a little before its first window
        t0 = 0.0 if stage == 1 or not starts else max(min(starts) - 0.1 * (t_end - min(starts)), 0.0)
        for r_i, name in enumerate(names):
            ax = axes[r_i, c]
            i = NAMES.index(name)
            spec = BY_NAME[name]
            ref = ref_all.get(name)
            prior = (priors or {}).get(name)
            prior_std = prior.std if prior is not None else np.inf
            for w in windows:
                end = w["end"] if w["end"] is not None else t_end
                if end >= t0:
                    ax.axvspan(max(w["start"], t0), end, color=_WINDOW_COLOR[w["stage"]], alpha=0.10, lw=0)
            ran = any(w["stage"] == stage for w in windows)
            if rows and ran:
                sel = t >= t0
                val, sd = _column(rows, 2, i)
                # the band at full strength only where the data has narrowed it; while it is still
                # the prior's width it is drawn faintly (clipped by the axes, it would flood them)
                informed = sel & (sd < 0.5 * prior_std)
                for part, alpha in ((sel & ~informed, 0.06), (informed, 0.22)):
                    ax.fill_between(
                        t, val - 2 * sd, val + 2 * sd, where=part, color="tab:blue", alpha=alpha, lw=0, zorder=2
                    )
                ax.plot(t[sel], val[sel], color="tab:blue", lw=1.6, zorder=4)
                if has_ekf:
                    ev, _ = _column(rows, 3, i)
                    ax.plot(t[sel], ev[sel], color="tab:red", lw=1.1, ls="--", zorder=3)
                lim = _limits(val[sel], sd[sel], ref, prior_std)
            elif prior is not None:  # nothing learnt: the prior's ±2σ frames the real value, if known
                pool = [prior.value - 2 * prior.std, prior.value + 2 * prior.std] + ([ref] if ref is not None else [])
                lim = (min(pool), max(pool))
            else:
                lim = None
            if ref is not None:
                ax.axhline(ref, color="k", lw=1.3, zorder=5)
            p = (params or {}).get(name) or {}
            shown = ran and p.get("value") is not None and p.get("std") is not None
            if shown:
                marked = True
                # what the result reports can differ from the filter's line: the std widened where the
                # model does not explain the data, or the output-error fit's value (core.output_error)
                v, s = p["value"], p["std"]
                ax.errorbar([t_end], [v], yerr=2 * s, fmt="D", ms=5, color=_REPORTED, capsize=3, zorder=7)
                if lim is not None:
                    pad = 0.05 * (lim[1] - lim[0])
                    lim = (min(lim[0], v - pad), max(lim[1], v + pad))
            if lim is not None:
                ax.set_ylim(*lim)
            if prior is not None and lim is not None:
                if lim[0] <= prior.value <= lim[1]:
                    ax.axhline(prior.value, color="0.45", lw=0.9, ls=":", zorder=1)
                else:  # off the axes: say where, don't stretch them
                    above = prior.value > lim[1]
                    ax.annotate(
                        f"prior {prior.value:.4g} {'↑' if above else '↓'}",
                        xy=(0.01, 0.97 if above else 0.03),
                        xycoords="axes fraction",
                        va="top" if above else "bottom",
                        fontsize=8,
                        color="0.4",
                    )
            # room for the reported value at the end (the same in every panel: they share the column's x)
            ax.set_xlim(t0, t_end + (0.03 * (t_end - t0) if params else 0.0))
            ax.set_ylabel(f"{_SYMBOL[name]} [{spec.unit.replace('*', '·')}]")
            ax.grid(alpha=0.3)
            if not ran:
                caps = capabilities or {}
                own = caps.get(name)  # a parameter its stage runs without (I_x without a roll-rate gyro)
                cannot = caps.get(str(stage))
                if own:
                    why = f"{name} is not estimated on this car:\n{_wrap(own)}"
                elif cannot:
                    why = f"stage {stage} cannot run on this car:\n{_wrap(cannot)}"
                else:
                    why = f"stage {stage} had no window"
                ax.text(
                    0.5,
                    0.5,
                    why,
                    transform=ax.transAxes,
                    ha="center",
                    va="center",
                    fontsize=9,
                    color="0.3",
                    bbox={"boxstyle": "round,pad=0.3", "fc": "white", "ec": "0.8"},
                    zorder=6,
                )
            head = f"({'abc'[r_i]}) {spec.description}"
            ax.set_title(head, fontsize=10, loc="left")
            if p.get("value") is not None:
                text = f"{p['value']:.4g} ± {p['std']:.2g}  {p.get('status', '').replace('_', ' ')}"
                if p.get("valid") is False and p.get("status") in ("converged", "uncertain"):
                    text += ", not valid"  # the reason is in the table and the JSON
                x = p.get("extra") or {}
                if x.get("C_alpha_front") is not None:  # the line is the axles' mean: say what each is
                    text += f"\nmean of front {x['C_alpha_front']:.4g}, rear {x['C_alpha_rear']:.4g}"
                if ref is not None:
                    text += f"\nreal {ref:.4g} ({100 * (p['value'] - ref) / ref:+.1f} %)"
                ax.text(
                    0.99,
                    0.04,
                    text,
                    transform=ax.transAxes,
                    ha="right",
                    va="bottom",
                    fontsize=8,
                    bbox={"boxstyle": "round,pad=0.25", "fc": "white", "ec": "0.8", "alpha": 0.9},
                    zorder=6,
                )
        axes[0, c].annotate(
            f"stage {stage} (cf. the paper's Figure {fig_no})",
            xy=(0.5, 1.18),
            xycoords="axes fraction",
            ha="center",
            fontsize=11,
            weight="bold",
        )
        axes[-1, c].set_xlabel("time since start of log [s]")
    legend = [
        Line2D([], [], color="k", lw=1.3, label="real value" if truth else "real value (pass --truth)"),
        Line2D([], [], color="tab:blue", lw=1.6, label="UKF"),
        Patch(color="tab:blue", alpha=0.2, label="UKF ±2σ"),
    ]
    if marked:
        legend.append(Line2D([], [], color=_REPORTED, marker="D", ms=5, ls="", label="reported ±2σ"))
    if has_ekf:
        legend.append(Line2D([], [], color="tab:red", lw=1.1, ls="--", label="EKF"))
    if priors:
        legend.append(Line2D([], [], color="0.45", lw=0.9, ls=":", label="prior"))
    legend += [
        Patch(color=_WINDOW_COLOR[1], alpha=0.25, label="stage-1 window"),
        Patch(color=_WINDOW_COLOR[2], alpha=0.25, label="stage-2 window"),
    ]
    fig.legend(handles=legend, loc="lower center", ncol=len(legend), fontsize=9, frameon=False)
    # a name is text, not math: a vehicle or log named "$^$" made matplotlib's math parser raise
    fig.suptitle(title or "vdp estimates", fontsize=12, parse_math=False)
    fig.tight_layout(rect=(0, 0.04, 1, 0.97))
    return fig


NAMED_DRIVES = 40  # drives per vehicle that fleet_figure names a row each


def fleet_figure(rows: list[dict], vehicles: list[dict]):
    """Per vehicle (a row of panels) and parameter (a panel): each drive's value ± 2σ, the
    combination of its converged drives ± 2σ as a band, a flagged drive (it disagrees with the
    others, vehicles.parquet's ``flagged``) in red, and the drives not converged as hollow marks
    (they do not enter).  One picture of what runs.parquet and vehicles.parquet say in numbers."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.ticker import MaxNLocator

    from .fleet import usable

    names = [n for n in NAMES if any(r.get("parameter") == n for r in rows)]
    cars = sorted({v["vehicle"] for v in vehicles})
    comb = {(v["vehicle"], v["parameter"]): v for v in vehicles}
    run = {(r["vehicle"], r["log"], r["parameter"]): r for r in rows if r.get("parameter")}  # (one pass)
    n_rows, n_cols = max(len(cars), 1), max(len(names), 1)
    # a row per drive, named, up to NAMED_DRIVES; a vehicle with more gets smaller marks, its count
    # for a label and no more height (hundreds of drives had made a picture metres tall)
    height = 1.2 + n_rows * (0.6 + 0.3 * min(_most_drives(rows), NAMED_DRIVES))
    fig, axes = plt.subplots(n_rows, n_cols, figsize=(2.6 * n_cols, height), squeeze=False)
    for i, car in enumerate(cars):
        logs = sorted({r["log"] for r in rows if r.get("vehicle") == car and r.get("parameter")})
        many = len(logs) > NAMED_DRIVES
        ms, cap, lw = (2, 0, 0.6) if many else (4, 2, 1)
        for j, name in enumerate(names):
            ax = axes[i][j]
            v = comb.get((car, name), {})
            flagged, copies = set(v.get("flagged") or []), set(v.get("copies") or [])
            if v.get("value") is not None and math.isfinite(v["value"]):
                m, sd = v["value"], v["std"]
                ax.axvspan(m - 2 * sd, m + 2 * sd, color="tab:blue", alpha=0.18, lw=0)
                ax.axvline(m, color="tab:blue", lw=1)
            for k, lg in enumerate(logs):
                r = run.get((car, lg, name))
                if r is None or r.get("value") is None or not math.isfinite(r["value"]):
                    continue
                used = usable(r) and lg not in copies  # (as the combination takes it: fleet.combine)
                colour = "tab:red" if lg in flagged else ("black" if used else "grey")
                sd = r["std"] if r.get("std") is not None and math.isfinite(r["std"]) else 0.0
                face = colour if used else "white"
                ax.errorbar(r["value"], k, xerr=2 * sd, fmt="o", ms=ms, color=colour, mfc=face, capsize=cap, lw=lw)
            ax.set_ylim(-0.7, max(len(logs), 1) - 0.3)
            ax.set_yticks([] if many else range(len(logs)))
            ax.set_yticklabels([] if many or j else [Path(lg).name for lg in logs], fontsize=7, parse_math=False)
            ax.tick_params(axis="x", labelsize=7)
            ax.xaxis.set_major_locator(MaxNLocator(3))  # (a narrow panel's ticks ran into each other)
            unit = _unit(BY_NAME[name].unit)
            ax.set_title((f"{name} [{unit}]" if unit != "-" else name) if i == 0 else "", fontsize=9)
            if j == 0:
                # (names as text, not matplotlib's math: see figure)
                ax.set_ylabel(
                    f"{car}\n{len(logs)} drives, in name order" if many else car, fontsize=9, parse_math=False
                )
            p = v.get("p_value_kept")  # the consistency test of the drives combined
            if p is not None and math.isfinite(p):
                left_out = (v.get("dof") or 0) + 1 - (v.get("drives") or 0)  # (a flagged pair stays in)
                what = "χ² p of the rest" if left_out > 0 else "χ² p"
                ax.text(0.02, 0.98, f"{what} = {p:.2g}", transform=ax.transAxes, fontsize=6, va="top")
    title = (
        "drives (value ± 2σ; red: flagged as disagreeing; hollow: not used: not converged, not valid, or a copy "
        "of another log) and their "
        "combination (blue ± 2σ)"
    )
    fig.suptitle(textwrap.fill(title, 40 * n_cols), fontsize=8)  # (wrapped to a narrow figure's width)
    fig.tight_layout()
    return fig


def _most_drives(rows: list[dict]) -> int:
    per: dict[str, set] = {}
    for r in rows:
        if r.get("parameter"):
            per.setdefault(r["vehicle"], set()).add(r["log"])
    return max((len(v) for v in per.values()), default=1)


def fleet_plot(rows: list[dict], vehicles: list[dict], path: str | Path) -> None:
    """Write :func:`fleet_figure` to ``path`` (PNG, PDF or SVG by suffix)."""
    import matplotlib.pyplot as plt

    fig = fleet_figure(rows, vehicles)
    try:
        with replacing(path) as tmp:
            fig.savefig(tmp, dpi=110)
    finally:
        plt.close(fig)
