"""Compile every signature the estimator uses, once per install (and per version of the sources).

The first estimate that wants a compiled step calls :func:`ensure` (core.compiled): where the
cache is not complete it says so through the logger and compiles them all here, at once, so
that no later stage, axle mode or restarted filter compiles again, silently, mid-run.
deploy/bootstrap.sh runs :func:`warm` at set-up, so that no test (and no pair of Dask workers
at once) pays it.  Each call below passes arguments of the types and layouts the callers pass
(tests/test_kernels.py checks that a drive run after this compiles nothing more).
"""

from __future__ import annotations

import logging
import threading

import numpy as np

from .. import channels as ch
from . import batched, jit, kernels, lateral, longitudinal, passes, prepass
from .bounds import Bounds
from .supervisor import Supervisor

log = logging.getLogger(__name__)

_lock = threading.Lock()


def ensure(say=None) -> None:
    """Compile (or load) everything now if the cache is not complete, and say so, once: through
    ``say`` (the CLI's print) or else the logger.  The first run after an install spends
    jit.FIRST_COMPILE here."""
    if jit.cached():
        return
    with _lock:
        if jit.cached():
            return
        note = (
            f"compiling the estimator's steps once for this install ({jit.FIRST_COMPILE}); "
            f"later runs load them from {jit.cache_dir()}"
        )
        if say is None:
            log.warning("%s", note)
        else:
            say(note)
        warm()


def warm() -> None:
    """Compile (or load) every compiled function the estimator calls, on small inputs of the
    types it passes, then mark the cache complete (core.jit.cached)."""
    lat = lateral.Known(m=1500.0, L=2.7, r=0.3, k_phi=6e4, c_phi=4e3, l_f=1.3, h=0.55, C_K=10.0)
    b2 = Bounds(lateral.N_X, log=(lateral.C_F, lateral.C_R, lateral.I_Z, lateral.I_X))
    x2 = b2.from_si(np.array([0.0, 0.1, 0.0, 0.0, 6e4, 6e4, 2000.0, 500.0, 1.3]))
    f = kernels.LateralUKF(x2, np.eye(lateral.N_X) * 1e-4, np.eye(lateral.N_X) * 1e-8, np.eye(3) * 1e-4,
                   np.ones(lateral.N_X), None, None, b2, lat, lateral.CONSIDER)  # fmt: skip
    u = np.array([[0.02, 15.0, 50.0, 0.1]] * 3)
    f.predict(0.04, u)
    f.update(np.array([0.1, 0.0, 1.5]), np.array([True, False, True]), u[-1])
    j, w = f._grid(3, 4)
    Y = np.ones((3, 12))
    sig = f._sigmas  # a filter just built passes (0, n) points, the same type (core.compiled.sig_in)
    kernels.lat_run(
        np.arange(3) * 0.02,
        Y,
        np.zeros((3, 5)),
        np.zeros(3, dtype=bool),
        0,
        3,
        np.arange(11),
        f._f.x,
        f._f.P,
        sig,
        f._lam_n,
        f._Wm,
        f._Wc,
        f.Q_rate,
        f.R,
        f.scale,
        f._kind,
        f._lo,
        f._span,
        f._known,
        f._c,
        j,
        w,
        4,
        np.zeros(7),
        np.array([0.05, 2.0, 50.0, 1e-6, 25.0, 1.0]),
        np.zeros((3, 5)),
        np.ones(10),
        np.zeros((4, 10)),
        np.zeros((4, 50)),
        np.zeros((3, 8)),
    )
    lon = longitudinal.Known(m=1500.0, L=2.7, r=0.3, J=1.0)
    b1 = Bounds(longitudinal.N_X, log=(longitudinal.H, longitudinal.C_K), logit={longitudinal.L_F: (0.0, 2.7)})
    x1 = b1.from_si(np.array([1.3, 0.55, 10.0, 0.0, 0.0, 0.0, 0.0]))
    g = kernels.LongitudinalUKF(x1, np.eye(longitudinal.N_X) * 1e-4, np.eye(longitudinal.N_X) * 1e-9, np.eye(2) * 1e-4,
                        np.ones(longitudinal.N_X), None, None, b1, lon)  # fmt: skip
    u1 = np.array([100.0, 50.0, 0.5, 15.0, 0.05, 0.1, 0.1])
    g.predict(0.1, u1)
    g.update(np.array([50.2, 50.1]), np.ones(2, dtype=bool), u1)
    ts = np.arange(5) * 0.02
    prm = np.array([0.5, 1.0, 0.2, 0.1, 2.0, 1.0])
    kernels.lon_block(g._f.x, g._f.P, g._lam_n, g._Wm, g._Wc, g.Q_rate, g.scale, g._kind, g._lo, g._span, g._known, ts,
              np.tile(u1, (5, 1)), np.tile([50.2, 50.1], (5, 1)), 0.1, np.eye(2), prm)  # fmt: skip
    sig = g._sigmas
    kernels.lon_run(ts, np.ones((5, 12)), np.ones((5, 5)), np.zeros(5, dtype=bool), 0, 5, np.arange(7), g._f.x,
        g._f.P, sig, g._lam_n, g._Wm, g._Wc, g.Q_rate, g.scale, g._kind, g._lo, g._span, g._known, np.eye(2), prm,
        np.zeros(7), np.array([0.05, 5.0, 50.0, 20.0, 200.0, 3000.0]), np.zeros((5, 10)), np.empty((2, 7)),
        np.empty((2, 2)), np.empty((2, 2, 2)))  # fmt: skip
    U = np.tile(u1, (50, 1))
    kernels.lon_solve(b1, lon, U, np.tile([50.2, 50.1], (50, 1)), np.tile(np.eye(2) * 1e-4, (50, 1, 1)), x1,
              np.eye(longitudinal.N_X), [x1], iters=2)  # fmt: skip
    kernels.lon_hx_rows(b1.to_si(x1), U, kernels.lon_known(lon))
    n = 60
    tt = np.arange(n) * 0.04
    d = 0.03 * np.sin(tt)
    steps = np.stack([d[1:], d[:-1], d[1:]], axis=1)  # output_error._Pre of the steps: (n - 1, 2 sub + 1)
    first = np.zeros(n, dtype=bool)
    first[0] = True
    theta = np.array([[6e4, 6e4, 2000.0]])
    no_bend = np.empty((0, 0))
    for bend in ((no_bend, no_bend), (np.ones((1, n)), np.ones((1, n)))):
        kernels.oe_states(steps.copy(), np.cos(steps), np.full_like(steps, 15.0), np.zeros_like(steps),
                          np.zeros_like(steps), np.zeros_like(steps), np.full(n - 1, 0.04), np.linspace(0.0, 1.0, 3),
                          first, theta, np.zeros(1), *bend, 1.3, 2.7, 1500.0)  # fmt: skip
    _prepass()
    jit.mark_cached()


def _prepass() -> None:
    """core.prepass.prepass as TwoStageEstimator.handle_block calls it."""
    n = 3
    Y = np.zeros((n, ch.N))
    F, A = np.ones((n, ch.N), dtype=bool), np.zeros((n, ch.N))
    blk, first = np.zeros((2, batched.N_CODES)), np.full((2, batched.N_CODES), -1, np.int64)
    need = np.arange(2, dtype=np.int64)
    p = np.ones(passes.N_PARAMS)  # (a time constant of 0 would divide by zero)
    prepass.prepass(
        np.arange(n) * 0.02,
        Y,
        F,
        A,
        np.zeros(n, dtype=bool),
        np.zeros(n, dtype=np.int64),
        np.zeros(passes.N_STATE),
        p,
        batched.CHANNELS,
        need,
        need,
        0,
        blk,
        first,
        np.empty((n, 5)),
        np.empty(n, dtype=np.int64),
    )
    Supervisor().gates.block(np.arange(n) * 0.02, Y, np.zeros(n, dtype=bool))  # core.gates' pass
