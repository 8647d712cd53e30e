"""Cost of stage 2's model calls, the inner loop of replay once stage 2 runs.

    python benchmarks/bench_model.py

Times ``lateral.fx`` (one 40 ms filter step: 4 midpoint sub-steps, the roll map)
for the UKF's 17 sigma points (8 states) and for the EKF's single state, plus ``hx`` and the
EKF's Jacobians, on the paper's car, wall time per call (best of 5 repeats).
"""

from __future__ import annotations

import sys
import timeit
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "service"))

import numpy as np  # noqa: E402

from vdp.core import lateral  # noqa: E402


def main() -> int:
    k = lateral.Known(m=1500.0, L=2.7, r=0.3, k_phi=2.06e6, c_phi=1.0e5, l_f=1.4, h=0.637, C_K=10.0)
    rng = np.random.default_rng(1)
    x = np.array([0.1, 0.15, 0.001, 0.01, 6.69e4, 6.0e4, 2000.0, 4175.0, 1.4])
    n_sig = 2 * len(x) + 1
    sig = x + rng.normal(size=(n_sig, len(x))) * 0.01 * np.abs(x)
    u = np.column_stack([np.linspace(0.02, 0.03, 3), np.full(3, 20.0), np.full(3, 67.0), np.zeros(3)])
    row = u[-1]
    calls = [
        (f"fx, {n_sig} sigma points (UKF)", lambda: lateral.fx(sig, 0.04, u, k)),
        ("fx, one state (EKF)", lambda: lateral.fx(x, 0.04, u, k)),
        (f"hx, {n_sig} sigma points", lambda: lateral.hx(sig, row, k)),
        ("jac_f + jac_h, one state", lambda: (lateral.jac_f(x, row, k), lateral.jac_h(x, row, k))),
    ]
    n = 2000
    for name, fn in calls:
        best = min(timeit.repeat(fn, number=n, repeat=5)) / n
        print(f"{name:28s} {best * 1e6:7.1f} us/call")
    return 0


if __name__ == "__main__":
    sys.exit(main())
