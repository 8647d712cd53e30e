"""Vehicle models that vdp did not derive its estimator from: independent truth for benchmarks and tests.

vdp's own simulator (:mod:`vdp.sim.vehicle`) shares the estimator's model, so agreeing
with it proves little.  The models here share no code with the estimator's process
models (``vdp.core``) nor with :mod:`vdp.sim.vehicle`:

* ``brush`` (:mod:`.brush`): written here from first principles: four wheels, brush
  tyres with combined slip and load-dependent stiffness, sprung mass rolling about a
  roll axis and pitching about a pitch centre, instantaneous and elastic load
  transfer, aerodynamic drag and rolling resistance.
* ``mb`` (:mod:`.mb`): the multi-body model ``vehicle_dynamics_mb`` of the CommonRoad
  vehicle models (package ``vehiclemodels``, BSD-3, installed with vdp's ``bench``
  extra): Pacejka Magic-Formula tyres with combined slip, sprung and unsprung masses,
  suspension roll and pitch, tyre vertical compliance, and the library's own cars.
  vdp adds only what the library lacks: wheel torques from the driver, drag and
  rolling resistance (see the module).

Only the manoeuvre definition (:mod:`vdp.sim.scenario`), the driver
(:mod:`vdp.sim.driver`, a speed and steering controller), the sensor noise model
(:mod:`vdp.sim.sensors`) and the CAN encoding (:mod:`vdp.sim.encode`) are shared with
vdp's simulator: the drive reaches the estimator through the same DBC -> candump ->
``vdp replay`` path.

What "truth" means on a model vdp did not write (written into every truth JSON under
``definitions``; see :data:`DEFINITIONS`).  The profile's known constants are what a
user would measure: mass, wheelbase, rolling radius, wheel inertia, and the elastic
roll stiffness and damping a K&C rig gives (brush: the model's own springs and
dampers; mb: fitted to a roll-moment step on the model, :func:`.mb.kc_roll`).
"""

from __future__ import annotations

from ...errors import ConfigError

DEFINITIONS = {
    "l_f": "distance from the front axle to the CG of the whole car, from the static axle loads: "
    "l_f = L * F_z,rear,static / (m g)",
    "h": "the height that sets longitudinal load transfer: the slope of the rear axle's load against m a_x / L "
    "on the model's own straight-line drive (least squares with a constant and v^2 for drag); it differs "
    "from the geometric CG height by the static pitch shift and the unsprung masses",
    "C_K": "small-slip longitudinal stiffness of the tyre law, dF_x/dkappa at kappa = 0, alpha = 0, zero camber, "
    "divided by the axle load, per axle at the mean axle loads of the straight-line (stage 1) part of the drive; "
    "the single value is the mean of front and rear (kappa = (omega r - v_wheel) / v_wheel)",
    "C_alpha": "small-slip cornering stiffness per axle (both wheels), dF_y/dalpha at alpha = 0, kappa = 0, zero "
    "camber, at the mean axle loads of the steering (stage 2) part of the drive; the single value is the mean of "
    "front and rear [N/rad]. The drive's forces are not C_alpha alpha: in a steady turn at a_y = 2 (3) m/s^2 a "
    "brush axle gives 0.93 (0.89) of it from the tyre's curvature and 0.92 (0.88) with the turn's lateral load "
    "transfer, a Magic-Formula axle 0.99 (0.97) (its force is proportional to the load, so transfer costs nothing); "
    "mb's tyres add camber thrust as the body rolls (the library's Magic Formula shifts by sign(camber): about "
    "2 % of F_z per wheel at zero camber, in phase with the cornering force), which is not part of C_alpha "
    "(benchmarks/stage2_mismatch.py secant, terms)",
    "I_z": "yaw inertia of everything that yaws with the car, as the model's yaw equation has it [kg m^2]. brush: "
    "the parameter I_z of I_z r' = M_z with moments about the whole car's CG, unsprung masses and wheels included "
    "(the model has no other yaw inertia). mb: the library's I_z (IZZ), its only yaw inertia; the library takes "
    "moments about the sprung mass's CG and gives the unsprung masses neither yaw inertia nor a moment of their "
    "lateral inertia force there, so they are not in it (m_uf a^2 + m_ur b^2 would add 12 % on bmw_320i, 10 % on "
    "vw_vanagon, to a car the library does not simulate). The whole car's CG (l_f) is 1.6 cm (bmw_320i), 0.9 cm "
    "(vw_vanagon) behind the sprung CG: a parallel-axis shift below 0.3 kg m^2, but about it the library's yaw "
    "balance keeps a moment (m_ur b - m_uf a) a_y (17 and 14 kg m times a_y) that no inertia describes",
    "I_x": "roll inertia of the sprung mass as eq 9 sees it from where the IMU sits: I_xx,s + m_s d (d - e), "
    "d = height of the sprung CG above the roll axis, e = height of the IMU above it (brush: IMU on the roll axis, "
    "so I_xx,s + m_s d^2; mb: IMU at the sprung CG, so I_xx,s); roll rate is the sprung body's [kg m^2]",
}

MODELS = ("brush", "mb")
# the ones that stay above 5 m/s (see brush.py on the wheel modes)
SCENARIOS = ("paper", "stage1", "stage2", "ordinary_rolling")


def cars(model: str) -> tuple[str, ...]:
    """The car sets of a model."""
    if model == "brush":
        from .brush import CARS

        return tuple(CARS)
    if model == "mb":
        from .mb import CARS

        return tuple(CARS)
    raise ConfigError(f"unknown model '{model}'; choose one of {', '.join(MODELS)}")


def get_model(model: str, car: str | None = None, **world):
    """A fresh model instance: ``get_model("brush", "small")``, ``get_model("mb", "bmw_320i")``.

    ``world`` (issue 28, vdp.sim.road): ``load`` kg undeclared, ``road``, ``imu``; the brush model
    takes them, mb only on a flat road with a road-aligned IMU and no load.
    """
    names = cars(model)
    car = car or names[0]
    world = {k: v for k, v in world.items() if v}
    if model == "brush":
        from .brush import model as make
    else:
        from .mb import model as make

        if world:
            raise ConfigError(f"model 'mb' does not take {', '.join(world)} yet; use 'brush'")
    return make(car, **world)
