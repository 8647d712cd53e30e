"""Replay results as JSON, a terminal table and a plot (in the spirit of the paper's Figs 5 and 7)."""

from __future__ import annotations

import json
import math
from pathlib import Path

from .core.params import BY_NAME, NAMES
from .errors import ConfigError


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


def compare(params: dict, truth: dict) -> dict:
    """Relative error of each estimate, and whether truth is inside value +- 2 std."""
    out = {}
    for name in NAMES:
        t = truth["parameters"].get(name)
        e = params.get(name) or {}
        v, sd = e.get("value"), e.get("std")
        if t is None or v is None:
            out[name] = {"truth": t, "rel_error": None, "within_2std": None}
            continue
        out[name] = {"truth": t, "rel_error": (v - t) / t, "within_2std": bool(sd is not None and abs(v - t) <= 2 * sd)}
    return out


_DRIVE_WORDS = {1: "straight-line acceleration and braking", 2: "steady speed with continuous steering"}


def stage_lines(result: dict) -> list[str]:
    """One line per stage that produced nothing: why it could not run, and what the drive offered."""
    lines = []
    exc = result.get("supervisor", {}).get("excitation", {})
    for stage in ("1", "2"):
        ran = any(str(w["stage"]) == stage for w in result.get("windows", []))
        if ran:
            continue
        why = result.get("capabilities", {}).get(stage)
        if why:
            lines.append(f"stage {stage} cannot run: {why}")
        e = exc.get(stage) or {}
        if e.get("of"):
            blocker = e.get("main_blocker")
            if e["seconds"] > 0 and not why:
                blocker = result["supervisor"]["reasons"].get(stage, blocker)
            lines.append(
                f"stage {stage}: the drive had {e['seconds']:.1f} of {e['of']:.1f} s of "
                f"{_DRIVE_WORDS[int(stage)]}" + (f"; mostly: {blocker}" if blocker else "")
            )
    return lines


def _fmt(v, digits=4):
    if v is None:
        return "-"
    if v == 0 or 1e-3 <= abs(v) < 1e5:
        return f"{v:.{digits}g}"
    return f"{v:.3e}"


def table(report: dict) -> str:
    """A fixed-width table of the six parameters (UKF), the EKF baseline and, if known, the truth."""
    params, ekf = report["parameters"], report.get("baseline_ekf") or {}
    cmp_ = report.get("truth_comparison") or {}
    cmp_ekf = report.get("truth_comparison_ekf") or {}
    head = f"{'param':8} {'value':>10} {'± std':>10} {'unit':7} {'status':17} {'EKF value':>10}"
    if cmp_:
        head += f" {'truth':>10} {'UKF err':>8} {'EKF err':>8}"
    lines = [head, "-" * len(head)]
    for name in NAMES:
        p = params[name]
        e = ekf.get(name, {})
        row = (
            f"{name:8} {_fmt(p['value']):>10} {_fmt(p['std'], 2):>10} {p['unit']:7} "
            f"{p['status']:17} {_fmt(e.get('value')):>10}"
        )
        if cmp_:
            c, ce = cmp_[name], cmp_ekf.get(name, {})
            err = "-" if c["rel_error"] is None else f"{100 * c['rel_error']:+.2f}%"
            err_e = "-" if ce.get("rel_error") is None else f"{100 * ce['rel_error']:+.2f}%"
            row += f" {_fmt(c['truth']):>10} {err:>8} {err_e:>8}"
        lines.append(row)
    return "\n".join(lines)


def _finite_or_none(obj):
    """JSON never carries NaN: non-finite floats become null."""
    if isinstance(obj, float):
        return obj if math.isfinite(obj) else None
    if isinstance(obj, dict):
        return {k: _finite_or_none(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_finite_or_none(v) for v in obj]
    return obj


def write_json(report: dict, path: str | Path) -> None:
    Path(path).write_text(json.dumps(_finite_or_none(report), indent=2, allow_nan=False) + "\n", encoding="utf-8")


def plot(
    trace, windows, path: str | Path, truth: dict | None = None, title: str = "", params: dict | None = None
) -> None:
    """Each parameter over time with its +-2 sigma band, UKF and EKF, truth if known.

    ``params`` (the result's UKF parameters) labels each panel with its final status.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    import numpy as np

    rows = list(trace)
    fig, axes = plt.subplots(3, 2, figsize=(12, 10), sharex=True)
    if rows:
        t = np.array([r[0] for r in rows])
        kinds = [("UKF", 2, "tab:blue")] + ([("EKF", 3, "tab:red")] if len(rows[0]) > 3 else [])
        for i, name in enumerate(NAMES):
            ax = axes.flat[i]
            ukf_val = None
            for label, col, color in kinds:
                val = np.array([np.nan if r[col][i][0] is None else r[col][i][0] for r in rows])
                sd = np.array([np.nan if r[col][i][1] is None else r[col][i][1] for r in rows])
                ax.plot(t, val, color=color, lw=1.2, label=label)
                if label == "UKF":
                    ukf_val = val
                    ax.fill_between(t, val - 2 * sd, val + 2 * sd, color=color, alpha=0.18, lw=0, label="UKF ±2σ")
            if truth and truth.get("parameters", {}).get(name) is not None:
                ax.axhline(truth["parameters"][name], color="k", ls="--", lw=1, label="truth")
            for w in windows:
                end = w["end"] if w["end"] is not None else t[-1]
                ax.axvspan(w["start"], end, color="tab:green" if w["stage"] == 1 else "tab:orange", alpha=0.07, lw=0)
            spec = BY_NAME[name]
            status = (params or {}).get(name, {}).get("status")
            ax.set_title(
                f"{name} [{spec.unit}] (stage {spec.stage})" + (f": {status.replace('_', ' ')}" if status else ""),
                fontsize=10,
            )
            # keep the axis on the estimate, not on a wide early band
            finite = ukf_val[np.isfinite(ukf_val)]
            ref = [truth["parameters"][name]] if truth and truth.get("parameters", {}).get(name) else []
            pool = np.concatenate([finite[len(finite) // 3 :], ref]) if len(finite) else np.array(ref)
            if len(pool):
                lo, hi = float(np.min(pool)), float(np.max(pool))
                pad = max(0.15 * (hi - lo), 0.05 * abs(hi) + 1e-9)
                ax.set_ylim(lo - 3 * pad, hi + 3 * pad)
            ax.grid(alpha=0.3)
        axes.flat[0].legend(fontsize=8, loc="best")
    for ax in axes[-1]:
        ax.set_xlabel("time since start of log [s]")
    fig.suptitle(title or "vdp estimates (shaded: green stage-1 windows, orange stage-2 windows)", fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
