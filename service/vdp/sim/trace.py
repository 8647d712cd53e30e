"""A scenario's truth physics alone, without sensors or a bus (tests, plots)."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np

from ..profile import Profile
from .base import DT, _profile, wheel_slips
from .driver import Driver, DriverConfig
from .scenario import Scenario, get_scenario
from .truth import axle_parameters, truth_parameters
from .vehicle import STATE, Model, Params


# -- physics-only trace (tests, plots) ------------------------------------------------
def trace(
    scenario: str | Scenario = "paper",
    profile: Profile | str | Path | None = None,
    *,
    params: Mapping[str, float] | None = None,
    dt: float = DT,
    every: int = 10,
    duration: float | None = None,
    driver: DriverConfig | None = None,
) -> dict[str, np.ndarray]:
    """Truth time series of a scenario, without sensors: states, inputs, forces, heading.

    Keys: ``t``, the state names of :data:`vdp.sim.vehicle.STATE`, ``T_f``, ``T_r``,
    ``delta``, ``v_cmd``, ``delta_cmd``, every :class:`vdp.sim.vehicle.Forces` field,
    and ``heading`` (integrated yaw angle).  Samples every ``every`` steps.
    """
    prof = _profile(profile, None)
    veh = prof.vehicle
    sc = scenario if isinstance(scenario, Scenario) else get_scenario(scenario, veh.wheelbase)
    model = Model(Params.from_vehicle(veh, {**truth_parameters(params), **axle_parameters(params)}))
    p = model.params
    drv = Driver(driver or DriverConfig(), p.m, p.r, p.J)
    T = sc.duration if duration is None else min(duration, sc.duration)
    n_steps = int(round(T / dt))
    keys = (
        ("t",)
        + STATE
        + ("T_f", "T_r", "delta", "v_cmd", "delta_cmd")
        + ("a_x", "a_y", "F_zf", "F_zr", "F_xf", "F_xr", "F_yf", "F_yr", "s_f", "s_r", "alpha_f", "alpha_r")
        + ("heading",)
    )
    rows = []
    x = model.straight(sc.v0)
    hint, psi = 0, 0.0
    for n in range(n_steps):
        t = n * dt
        v_cmd, a_cmd, d_cmd, hint = sc.command(t, hint)
        tf, tr, delta = drv.update(dt, v_cmd, a_cmd, d_cmd, x[0], wheel_slips(x, p.r))
        x1, e = model.advance(x, tf, tr, delta, dt, drv.next_delta(sc.command(t + dt, hint)[2]))
        if n % every == 0:
            rows.append((t, *x, tf, tr, delta, v_cmd, d_cmd, *e, psi))
        psi += 0.5 * dt * (x[2] + x1[2])
        x = x1
    arr = np.array(rows, dtype=float).reshape(-1, len(keys))
    return {k: arr[:, i] for i, k in enumerate(keys)}
