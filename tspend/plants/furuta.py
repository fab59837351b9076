"""The Furuta (rotary inverted) pendulum domain: the QUBE-Servo 2 rig, on both backends.

The equations of motion are not written here: both plants are the compiled MJCF read by
the articulated domain (:class:`~tspend.plants.articulated.machine.Machine`), whose
equations are derived from the model by Lagrange (:mod:`tspend.plants.articulated.derive`,
docs/articulated.md); docs/furuta.md gives the rig's numbers and their sources, and the
hand-written equations it derives are a test oracle (tests/oracles/furuta_equations.py).
This module is what the rest of tspend asks about the machine: the scenario's ``[plant]``
configuration (``furuta_ode``, ``furuta_mujoco``), the roles of the MJCF's joints (hinge
``arm`` driven by the motor, hinge ``pendulum`` carried by the arm), the model the
baselines assume, labels and units, the default task (view ``pendulum``,
``pendulum_dot``; fall angle pi/2) and the 3D drawing.

The state is MuJoCo's: ``[arm, pendulum, arm_dot, pendulum_dot]`` (rad, rad/s), the
pendulum's angle measured from the upright.  ``u`` is the motor voltage (V, clipped to the
amplifier's +/-10 V as MuJoCo clips ctrl), ``d`` a torque on the pendulum joint (N m).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Sequence

import numpy as np

from tspend.config import PlantConfig
from tspend.plants.drawing.furuta import FurutaDrawing
from tspend.runtime.errors import ScenarioError
from tspend.plants.articulated.domain import (INTEGRATOR_CHOICES, ArticulatedDomain,
    ArticulatedMujoco, ArticulatedODE, pumped_full_model)
from tspend.plants.articulated.machine import Machine, open_spec
from tspend.plants.base import InputInfo, MachinePlant, Plant, read_as, velocity_name
from tspend.plants.domain import (FULL_STATE, PUMPED_ENERGY, SYMBOLIC, VIEW_MODEL, Backend, Domain,
    FullModel, PlantLabels, Quantity, TaskDefaults)

if TYPE_CHECKING:
    from tspend.config import Scenario

__all__ = ["FurutaConfig", "FurutaMujocoConfig", "FurutaODE", "MujocoFuruta", "FurutaDomain",
           "coefficients", "load_furuta", "DOMAIN"]

#: where the real arm's cable stops it, rad (+/-135 deg): the default task's joint limit
ARM_STOP_RAD = 2.356


@dataclass(frozen=True)
class FurutaConfig(PlantConfig):
    """The Furuta pendulum on the analytic backend: the equations derived from
    models/furuta.xml (the QUBE-Servo 2's published numbers, docs/furuta.md); ``x0`` is the
    view ``[pendulum, pendulum_dot]``, the arm starting at rest at 0.  ``model_values``:
    what ``[randomize]`` drew of the model's numbers (not a ``[plant]`` key)."""

    x0: tuple[float, ...] = (0.05, 0.0)
    model_values: tuple = field(default=(), metadata={"internal": True})


@dataclass(frozen=True)
class FurutaMujocoConfig(FurutaConfig):
    """A Furuta MJCF stepped by MuJoCo, read as it is (its ODE is derived from it)."""

    model: str = "models/furuta.xml"
    arm_joint: str = "arm"
    pendulum_joint: str = "pendulum"
    actuator: str = "motor"
    #: physics timestep, s (0 keeps the model's); dt must be a whole multiple of it
    timestep: float = field(default=0.0, metadata={"low": 0.0})
    #: MuJoCo's integrator of the model ("" keeps the model's; the ODE is stepped by RK4)
    integrator: str = field(default="", metadata={"choices": INTEGRATOR_CHOICES})
    #: the pendulum joint's viscous damping, N m s/rad (negative keeps the model's, Quanser's
    #: 0.0005); the least certain number of the rig (docs/furuta.md), so a scenario may
    #: take another rig's identified value
    pendulum_damping: float = -1.0


def load_furuta(model_path: str | Path, arm: str = "arm", pendulum: str = "pendulum",
                actuator: str = "motor", timestep: float | None = None,
                pendulum_damping: float | None = None,
                values: tuple[tuple[str, float], ...] = (), integrator: str = "") -> Machine:
    """The Furuta MJCF at ``model_path`` compiled (``timestep``, ``pendulum_damping`` and
    then ``values``, the ``(BODY.mass | JOINT.damping | JOINT.armature, value)`` pairs of
    :mod:`~tspend.plants.articulated.model_numbers`, written into it when given) and read
    as an articulated machine whose pole is ``pendulum`` and whose ``u`` drives ``actuator``."""
    from tspend.plants.articulated.model_numbers import compile_with_values

    where = str(model_path)
    spec = open_spec(model_path, timestep, integrator)
    if pendulum_damping is not None:
        joint = spec.joint(pendulum)
        if joint is None:
            raise ScenarioError(f"{where}: no joint named {pendulum!r}")
        # MuJoCo 4's damping is [linear, polynomial terms]: only the linear one set
        damping = np.array(joint.damping, dtype=float)
        damping[0] = float(pendulum_damping)
        joint.damping = damping
    model = compile_with_values(spec, values, where)
    names = tuple(model.joint(j).name for j in range(model.njnt))
    for joint in (arm, pendulum):
        if joint not in names:
            raise ScenarioError(f"{where}: no joint named {joint!r} (joints: "
                                f"{', '.join(names) or 'none'})")
    if names != (arm, pendulum):
        raise ScenarioError(f"{where}: a Furuta pendulum has the two hinges {arm!r} then "
                            f"{pendulum!r}; the model has joints {', '.join(names)}")
    machine = Machine(model, where, actuator, poles=(pendulum,))
    if machine.actuated != 0:
        raise ScenarioError(f"{where}: actuator {actuator!r} does not drive joint {arm!r}")
    return machine


def _fit(f: Callable[[float], float], basis: Sequence[Callable[[float], float]]) -> np.ndarray:
    """The coefficients of ``f`` over the trigonometric ``basis`` (least squares over 16
    angles: exact to rounding for a trigonometric polynomial in that basis; a coefficient
    within rounding of 0, 1e-12 of the largest, is 0)."""
    angles = np.linspace(-math.pi, math.pi, 16, endpoint=False)
    A = np.array([[b(a) for b in basis] for a in angles])
    c = np.linalg.lstsq(A, np.array([f(a) for a in angles]), rcond=None)[0]
    c[np.abs(c) <= 1e-12 * np.max(np.abs(c))] = 0.0
    return c


def coefficients(machine: Machine) -> dict[str, float]:
    """The derived equations of a Furuta ``machine`` in the names docs/furuta.md writes them
    in (what ``parameters()`` reports): the mass matrix's entries ``m11 = a0 + a1 cos al +
    a2 sin al + a3 cos 2al + a4 sin 2al``, ``m12 = b0 + b1 cos al + b2 sin al``, ``m22``
    (kg m^2), the potential ``V = v_c cos al + v_s sin al`` (N m), each read off the
    derived ``M(q)`` and gravity torque, then the joints' damping and the motor's law."""
    nv = machine.nv
    Mw, r = np.zeros(nv * nv), np.zeros(nv)
    zeros = np.zeros(nv)

    def mass(al: float) -> np.ndarray:
        machine.module.dynamics(np.array([0.0, al]), zeros, np.zeros(len(machine.tree.actuators)),
                                zeros, machine.p, Mw, r)
        return Mw.reshape(nv, nv)

    c, s = math.cos, math.sin
    a = _fit(lambda al: mass(al)[0, 0], (lambda al: 1.0, c, s, lambda al: c(2 * al),
                                         lambda al: s(2 * al)))
    b = _fit(lambda al: mass(al)[0, 1], (lambda al: 1.0, c, s))
    # -dV/dal = v_c sin al - v_s cos al
    v = _fit(lambda al: machine.gravity_torque(np.array([0.0, al]))[1], (s, c))
    arm, pend = machine.tree.joints
    act = machine.actuator
    ctrl = act.ctrlrange or (-math.inf, math.inf)
    force = act.forcerange or (-math.inf, math.inf)
    return {"a0": a[0], "a1": a[1], "a2": a[2], "a3": a[3], "a4": a[4], "b0": b[0], "b1": b[1],
            "b2": b[2], "m22": float(mass(0.0)[1, 1]), "v_c": float(v[0]), "v_s": 0.0 - float(v[1]),
            "arm_damping": arm.damping, "pendulum_damping": pend.damping,
            "motor_gear": act.gear, "motor_gain": act.gain[0], "motor_bias": act.bias[0],
            "motor_bias_position": act.bias[1], "motor_bias_velocity": act.bias[2],
            "u_min": ctrl[0], "u_max": ctrl[1], "force_min": force[0], "force_max": force[1]}


def _named_task(arm: str, pendulum: str) -> TaskDefaults:
    """The domain's task on a plant whose joints are called ``arm`` and ``pendulum``."""
    return DOMAIN.task.renamed({"arm": arm, "pendulum": pendulum,
                                "arm_dot": velocity_name(arm),
                                "pendulum_dot": velocity_name(pendulum)})


class _Furuta:
    """What both Furuta plants say alike, over the articulated machine's."""

    machine: Machine
    domain = "furuta"

    @property
    def arm_joint(self) -> str:
        return self.machine.joint_names[0]

    @property
    def pendulum_joint(self) -> str:
        return self.machine.joint_names[1]

    def default_task(self) -> TaskDefaults:
        return _named_task(self.arm_joint, self.pendulum_joint)

    @property
    def inputs(self) -> tuple[InputInfo, ...]:
        """The motor's voltage within its control range, which both backends apply (the
        ODE clips u as MuJoCo clips ctrl), so the saturation metrics mean the same on each."""
        a = self.machine.actuator
        lo, hi = a.ctrlrange if a.ctrlrange is not None else (-math.inf, math.inf)
        m = self.machine
        # u is a voltage: the torque it applies at rest beside it
        return (InputInfo(a.name, m.input_unit, lo, hi, m.force_unit, m.force_per_unit),)

    def parameters(self) -> dict[str, float]:
        return coefficients(self.machine)


class FurutaODE(_Furuta, ArticulatedODE):
    """The derived equations of a Furuta MJCF stepped by the analytic RK4 (the generic
    loop: see :meth:`ArticulatedODE.compiled`).  The controller's view is ``[pendulum,
    pendulum_dot]``; the arm rides along as the extras ``arm`` and ``arm_dot``."""

    def __init__(self, machine: Machine) -> None:
        ArticulatedODE.__init__(self, machine)
        self.name, self.domain = "furuta_ode", "furuta"


class MujocoFuruta(_Furuta, ArticulatedMujoco):
    """The Furuta MJCF stepped by MuJoCo: ``u`` is the actuator's ctrl, ``d`` the
    generalised force on the pendulum joint; joint roles by name."""

    name = "furuta_mujoco"

    def __init__(self, machine: Machine) -> None:
        ArticulatedMujoco.__init__(self, machine)
        self.actuator = machine.actuator.name


def _build_ode(cfg: PlantConfig, model_path: Path) -> Plant:
    # the ODE of a MuJoCo scenario is the compiled model's: one machine, two backends
    return DOMAIN.ode_of(_build_mujoco(cfg, model_path))


def _build_mujoco(cfg: PlantConfig, model_path: Path) -> Plant:
    mj = cfg if isinstance(cfg, FurutaMujocoConfig) else FurutaMujocoConfig(
        kind="furuta_mujoco", x0=cfg.x0, state_bound=cfg.state_bound)
    return MujocoFuruta(load_furuta(model_path, mj.arm_joint, mj.pendulum_joint, mj.actuator,
                                    mj.timestep or None,
                                    mj.pendulum_damping if mj.pendulum_damping >= 0.0 else None,
                                    tuple(cfg.model_values), mj.integrator))


# -- the domain ---------------------------------------------------------------------------
class FurutaDomain(ArticulatedDomain):
    """The rotary inverted pendulum: the arm's motor balances the pendulum on the arm (an
    articulated machine: its machine, nominal values, view model and linearisation are
    :class:`~tspend.plants.articulated.domain.ArticulatedDomain`'s)."""

    name = "furuta"
    kinds = {"furuta_ode": Backend(FurutaConfig, _build_ode),
             "furuta_mujoco": Backend(FurutaMujocoConfig, _build_mujoco, mujoco=True)}
    labels = PlantLabels(
        states=(Quantity("alpha", "rad", "pendulum angle"),
                Quantity("alpha'", "rad/s", "pendulum angular velocity")),
        control=Quantity("u", "V", "motor voltage"),
        extras={"arm": Quantity("theta", "rad", "arm angle"),
                "arm_dot": Quantity("theta'", "rad/s", "arm angular velocity")},
        full_state=(Quantity("theta", "rad", "arm angle", "arm"),
                    Quantity("alpha", "rad", "pendulum angle", "pendulum"),
                    Quantity("theta'", "rad/s", "arm angular velocity", "arm_dot"),
                    Quantity("alpha'", "rad/s", "pendulum angular velocity", "pendulum_dot")),
        disturbance=Quantity("d", "N m", "torque on the pendulum joint"))
    #: the QUBE's arm turns on a cable that stops it near +/-135 deg (docs/furuta.md): the
    #: model leaves the joint free (its open loop may turn over), the task does not
    task = TaskDefaults(view=("pendulum", "pendulum_dot"), fall_angle=math.pi / 2,
                        pole="pendulum", limits=(("arm", ARM_STOP_RAD),))
    default_model = FurutaMujocoConfig.model
    provides = frozenset({VIEW_MODEL, FULL_STATE, SYMBOLIC, PUMPED_ENERGY})
    view_names = Domain.view_names  # the task's view, not the plant's

    def model_file(self, cfg: PlantConfig) -> str:
        return cfg.model if isinstance(cfg, FurutaMujocoConfig) else self.default_model

    def full_model(self, scenario: "Scenario", machine: Plant) -> FullModel:
        """The derived equations over ``[arm, pendulum, arm_dot, pendulum_dot]`` (the plant's
        joint names; no clips: the MPC bounds u itself; the arm turns about the vertical,
        its own energy left out: :func:`pumped_full_model`)."""
        m = read_as(machine, MachinePlant).machine
        return pumped_full_model(self.name, machine, m, coefficients(m))

    def fits_mjcf(self, joint_types: tuple[str, ...]) -> bool:
        return joint_types.count("hinge") == 2 and "slide" not in joint_types

    def fits_model(self, model: Any) -> bool:
        """Two hinges, the first (the arm) turning about the vertical: an acrobot or a
        reaction wheel, whose first hinge is horizontal, is the articulated domain's."""
        import mujoco

        if not super().fits_model(model):
            return False
        data = mujoco.MjData(model)
        mujoco.mj_kinematics(model, data)
        g = np.asarray(model.opt.gravity, dtype=float)
        axis = np.asarray(data.xaxis[0], dtype=float)
        n = float(np.linalg.norm(g))
        return n > 0.0 and abs(abs(float(axis @ g)) / n - 1.0) < 1e-6

    def inspect(self, model_path: str, names: dict[str, str] | None = None,
                dt: float | None = None) -> tuple[dict[str, Any], list[str]]:
        """The model's derived equations in docs/furuta.md's names, with the upright's
        linearisation's open-loop poles."""
        plant = MujocoFuruta(load_furuta(model_path))
        facts: dict[str, Any] = {"domain": self.name, "joints": list(plant.state_names[:2]),
                                 "actuator": plant.actuator, "timestep": plant.timestep,
                                 **coefficients(plant.machine)}
        A, _ = plant.machine.linearisation()
        facts["upright_poles"] = sorted(float(e.real) for e in np.linalg.eigvals(A))
        return facts, plant.departures(dt)

    def drawing(self, plant: Plant, scenario: "Scenario") -> FurutaDrawing:
        """The QUBE's drawing, its arm (motor axis to the pendulum's hinge) and pendulum
        (twice its hinge to its centre of mass) measured on the compiled model."""
        import mujoco

        m = read_as(plant, MachinePlant).machine.model
        data = mujoco.MjData(m)
        mujoco.mj_forward(m, data)
        axis = np.asarray(data.xaxis[0])
        reach = np.asarray(data.xanchor[1]) - np.asarray(data.xanchor[0])
        com = np.asarray(data.subtree_com[int(m.jnt_bodyid[1])]) - np.asarray(data.xanchor[1])
        return FurutaDrawing(arm_length=float(np.linalg.norm(reach - (reach @ axis) * axis)),
                             pendulum_length=2.0 * float(np.linalg.norm(com)))

    def chirp_amplitude(self, plant: Plant) -> float:
        """3 V: a third of the amplifier's range, enough to throw the pendulum over."""
        return 3.0

    def ode_of(self, plant: Plant) -> Plant:
        return FurutaODE(read_as(plant, MachinePlant).machine)


#: the Furuta domain
DOMAIN = FurutaDomain()
