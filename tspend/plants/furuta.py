"""The Furuta (rotary inverted) pendulum domain: the QUBE-Servo 2 rig, on both backends.

The equations of motion, the motor and the reading of a compiled model are
:mod:`tspend.plants.furuta_physics` (docs/furuta.md derives them and gives every source);
this module is what the rest of tspend asks about the machine: the scenario's ``[plant]``
configuration (``furuta_ode``, ``furuta_mujoco``), the roles of the MJCF's joints (hinge
``arm`` driven by the motor, hinge ``pendulum`` carried by the arm), both plants, the
model the baselines assume, labels and units, the default task (view ``pendulum``,
``pendulum_dot``; fall angle pi/2) and the 3D drawing.

The state is MuJoCo's: ``[arm, pendulum, arm_dot, pendulum_dot]`` (rad, rad/s), the
pendulum's angle measured from the upright.  ``u`` is the motor voltage (V, clipped to the
amplifier's +/-10 V as MuJoCo clips ctrl), ``d`` a torque on the pendulum joint (N m).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, NamedTuple, Sequence

import numpy as np
from numba.extending import register_jitable

from tspend.config import PlantConfig
from tspend.errors import DivergenceError, ScenarioError
from tspend.plants.analytic import COMPILED_RHS, AnalyticPlant
from tspend.plants.base import InputInfo, JointInfo, Plant, velocity_name
from tspend.plants.domain import (COMPILED_VIEW_ACCEL, FULL_ACCEL, FULL_ENERGY, FULL_STATE,
    PUMPED_ENERGY, SYMBOLIC, VIEW_MODEL, Backend, Domain, Drawing, FullModel, PlantLabels, PlantModel, Quantity, TaskDefaults,
    END_COLOR, bound_text)
from tspend.plants.furuta_physics import (FurutaMachine, FurutaParams, accelerations_factory,
    linearize, machine_accelerations, machine_rhs, params_from_model, pendulum_energy)

if TYPE_CHECKING:
    from tspend.config import Scenario
    from tspend.task import Bound

__all__ = ["FurutaConfig", "FurutaMujocoConfig", "FurutaODE", "MujocoFuruta", "FurutaDomain",
           "FurutaDrawing", "DOMAIN"]

COMPILED_RHS[FurutaMachine] = machine_rhs


@register_jitable
def _full_q_dd(machine: FurutaMachine, s: np.ndarray, u: float) -> tuple[float, float]:
    # s is MuJoCo's [arm, pendulum, arm_dot, pendulum_dot]; no disturbance in a model
    return machine_accelerations(machine, s, u, 0.0)


@register_jitable
def _full_energy(machine: FurutaMachine, s: np.ndarray) -> float:
    return pendulum_energy(machine, s[1], s[3])


# compiled full-state controllers (swing-up) reach the Furuta pendulum through these
FULL_ACCEL[FurutaMachine] = _full_q_dd
FULL_ENERGY[FurutaMachine] = _full_energy

#: where the real arm's cable stops it, rad (+/-135 deg): the default task's joint limit
ARM_STOP_RAD = 2.356

#: the state, as MuJoCo's qpos then qvel of models/furuta.xml
STATE_UNITS = ("rad", "rad", "rad/s", "rad/s")


@dataclass(frozen=True)
class FurutaConfig(PlantConfig):
    """The Furuta pendulum on the analytic backend: the QUBE-Servo 2's published numbers
    (:class:`~tspend.plants.furuta_physics.FurutaParams`); ``x0`` is the view
    ``[pendulum, pendulum_dot]``, the arm starting at rest at 0."""

    x0: tuple[float, ...] = (0.05, 0.0)


@dataclass(frozen=True)
class FurutaMujocoConfig(FurutaConfig):
    """A Furuta MJCF stepped by MuJoCo, read as it is (its ODE is read back from it)."""

    model: str = "models/furuta.xml"
    arm_joint: str = "arm"
    pendulum_joint: str = "pendulum"
    actuator: str = "motor"
    #: physics timestep, s (0 keeps the model's); dt must be a whole multiple of it
    timestep: float = field(default=0.0, metadata={"low": 0.0})
    #: the pendulum joint's viscous damping, N m s/rad (negative keeps the model's, Quanser's
    #: 0.0005); the least certain number of the rig (docs/furuta.md), so a scenario may
    #: take another rig's identified value
    pendulum_damping: float = -1.0


def _named_task(arm: str, pendulum: str) -> TaskDefaults:
    """The domain's task on a plant whose joints are called ``arm`` and ``pendulum``."""
    return DOMAIN.task.renamed({"arm": arm, "pendulum": pendulum,
                                "arm_dot": velocity_name(arm),
                                "pendulum_dot": velocity_name(pendulum)})


class FurutaODE(AnalyticPlant):
    """The Furuta ODE of :mod:`tspend.plants.furuta_physics` stepped by the analytic RK4.

    The controller's view is ``[pendulum, pendulum_dot]``; the arm rides along as the
    extras ``arm`` and ``arm_dot``.
    """

    domain = "furuta"

    def __init__(self, params: FurutaParams = FurutaParams(), arm: str = "arm",
                 pendulum: str = "pendulum") -> None:
        super().__init__(lambda t, s, u, d: 0.0, 2, "furuta_ode", hidden_names=("arm", "arm_dot"),
                         domain="furuta")
        self.params, self._machine = params, params.machine()
        self.arm_joint, self.pendulum_joint = arm, pendulum

    @property
    def state_names(self) -> tuple[str, ...]:
        a, p = self.arm_joint, self.pendulum_joint
        return (a, p, f"{a}_dot", f"{p}_dot")

    state_units = STATE_UNITS

    @property
    def joints(self) -> tuple[JointInfo, ...]:
        return (JointInfo(self.arm_joint, "hinge", "rad"),
                JointInfo(self.pendulum_joint, "hinge", "rad"))

    def default_task(self) -> TaskDefaults:
        return _named_task(self.arm_joint, self.pendulum_joint)

    @property
    def inputs(self) -> tuple[InputInfo, ...]:
        """The motor's voltage within the amplifier's range, which the ODE applies (it clips
        u as MuJoCo clips ctrl): both backends declare the bound they apply, so the
        saturation metrics mean the same on each."""
        lo, hi = (float(v) for v in self.params.ctrl_range)
        return (InputInfo("motor", "V", lo, hi),)

    def extras_index(self) -> np.ndarray:
        return np.array([0, 2], dtype=np.intp)

    def reset(self, x0: np.ndarray) -> None:
        x0 = np.asarray(x0, dtype=float)
        if x0.shape != (2,):
            raise ValueError(f"{self.name}: initial state must have 2 entries, got {x0.shape}")
        self.s[:] = (0.0, x0[0], 0.0, x0[1])
        self._clock[0] = 0.0

    def full_state(self) -> np.ndarray:
        return self.s.copy()

    def extras(self) -> dict[str, float]:
        return {"arm": float(self.s[0]), "arm_dot": float(self.s[2])}

    def parameters(self) -> dict[str, float]:
        return {k: float(v) for k, v in self._machine._asdict().items()}

    def _rhs_params(self) -> Any:
        return self._machine

    def compiled(self) -> None:
        """The compiled loop reads the view as the state's first entries; the Furuta's
        view is not, so the generic loop runs."""
        return None

    @property
    def gain_sign(self) -> int:
        a = machine_accelerations(self._machine, np.zeros(4), 1.0, 0.0)[1]
        b = machine_accelerations(self._machine, np.zeros(4), 0.0, 0.0)[1]
        return 1 if a >= b else -1


class MujocoFuruta(Plant):
    """The Furuta MJCF stepped by MuJoCo: ``u`` is the actuator's ctrl, ``d`` the
    generalised force on the pendulum joint; joint roles by name."""

    order = 2
    name = "furuta_mujoco"
    domain = "furuta"
    state_units = STATE_UNITS

    def __init__(self, model_path: str | Path, arm: str = "arm", pendulum: str = "pendulum",
                 actuator: str = "motor", timestep: float | None = None,
                 pendulum_damping: float | None = None) -> None:
        import mujoco

        self.model_path = Path(model_path)
        where = str(model_path)
        if not self.model_path.is_file():
            raise ScenarioError(f"{where}: model file not found")
        from tspend.plants.mjcf import read_spec

        spec = read_spec(where)  # within the size bounds
        try:
            if timestep:
                spec.option.timestep = float(timestep)
            if pendulum_damping is not None:
                joint = spec.joint(pendulum)
                if joint is None:
                    raise ScenarioError(f"{where}: no joint named {pendulum!r}")
                # MuJoCo 4's damping is [linear, polynomial terms]: only the linear one set
                damping = np.array(joint.damping, dtype=float)
                damping[0] = float(pendulum_damping)
                joint.damping = damping
            self.model = spec.compile()
        except ValueError as exc:
            raise ScenarioError(f"{where}: cannot compile MJCF: {exc}") from exc
        m = self.model
        for joint in (arm, pendulum):
            if mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_JOINT, joint) < 0:
                names = ", ".join(m.joint(j).name for j in range(m.njnt)) or "none"
                raise ScenarioError(f"{where}: no joint named {joint!r} (joints: {names})")
        if mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_ACTUATOR, actuator) < 0:
            raise ScenarioError(f"{where}: no actuator named {actuator!r}")
        self.arm_joint, self.pendulum_joint, self.actuator = arm, pendulum, actuator
        self.data = mujoco.MjData(m)
        ja, jp = m.joint(arm).id, m.joint(pendulum).id
        self._qa, self._qp = int(m.jnt_qposadr[ja]), int(m.jnt_qposadr[jp])
        self._va, self._vp = int(m.jnt_dofadr[ja]), int(m.jnt_dofadr[jp])
        self._act = m.actuator(actuator).id
        self._ts = float(m.opt.timestep)
        self._mj_step = mujoco.mj_step
        w = mujoco.mjtWarning
        self._warnings = [self.data.warning[int(k)] for k in
                          (w.mjWARN_BADQPOS, w.mjWARN_BADQVEL, w.mjWARN_BADQACC)]
        try:
            self._params: FurutaParams | None = params_from_model(m, arm, pendulum, actuator)
            self._departures: list[str] = []
        except ValueError as exc:
            self._params, self._departures = None, [str(exc)]
        self.reset(np.zeros(2))

    @property
    def params(self) -> FurutaParams:
        """The ODE of the compiled model (ScenarioError when the model departs from it)."""
        if self._params is None:
            raise ScenarioError(f"{self.model_path}: {self._departures[0]}")
        return self._params

    def mj_model(self) -> Any:
        return self.model

    @property
    def state_names(self) -> tuple[str, ...]:
        a, p = self.arm_joint, self.pendulum_joint
        return (a, p, f"{a}_dot", f"{p}_dot")

    @property
    def joints(self) -> tuple[JointInfo, ...]:
        """The arm and the pendulum, with the compiled model's ranges when limited."""
        m = self.model
        out = []
        for name in (self.arm_joint, self.pendulum_joint):
            j = m.joint(name).id
            rng = (float(m.jnt_range[j, 0]), float(m.jnt_range[j, 1])) if m.jnt_limited[j] else None
            out.append(JointInfo(name, "hinge", "rad", rng))
        return tuple(out)

    @property
    def inputs(self) -> tuple[InputInfo, ...]:
        """The motor's voltage, bounded by its ctrlrange when ``ctrllimited``."""
        m, a = self.model, self._act
        lo, hi = (float(v) for v in m.actuator_ctrlrange[a]) if m.actuator_ctrllimited[a] \
            else (-math.inf, math.inf)
        return (InputInfo(self.actuator, "V", lo, hi),)

    def default_task(self) -> TaskDefaults:
        return _named_task(self.arm_joint, self.pendulum_joint)

    def extras_index(self) -> np.ndarray:
        return np.array([0, 2], dtype=np.intp)

    @property
    def timestep(self) -> float:
        return self._ts

    def departures(self, dt: float | None = None) -> list[str]:
        """How this model departs from the Furuta ODE (empty: not at all)."""
        out = list(self._departures)
        if dt is not None and abs(round(dt / self._ts) * self._ts - dt) > 1e-9 * dt:
            out.append(f"dt = {dt:g} s is not a whole multiple of the timestep {self._ts:g} s")
        return out

    def reset(self, x0: np.ndarray) -> None:
        import mujoco

        x0 = np.asarray(x0, dtype=float)
        if x0.shape != (2,):
            raise ValueError(f"{self.name}: initial state must have 2 entries, got {x0.shape}")
        mujoco.mj_resetData(self.model, self.data)
        self.data.qpos[self._qp] = x0[0]
        self.data.qvel[self._vp] = x0[1]
        mujoco.mj_forward(self.model, self.data)

    def full_state(self) -> np.ndarray:
        q, v = self.data.qpos, self.data.qvel
        return np.array((q[self._qa], q[self._qp], v[self._va], v[self._vp]))

    def parameters(self) -> dict[str, float]:
        return {k: float(v) for k, v in self.params.machine()._asdict().items()}

    def check_sample_time(self, dt: float) -> None:
        self._substeps(dt)

    def _substeps(self, dt: float) -> int:
        from tspend.plants.mujoco_plant import whole_substeps

        return whole_substeps(dt, self._ts, self.model_path)

    def step(self, u: float, d: float, dt: float) -> None:
        from tspend.plants.mujoco_plant import instability_error, refuse_huge_input

        refuse_huge_input(self.name, u, d, self.data.time)
        t0 = self.data.time
        self.data.ctrl[self._act] = u
        self.data.qfrc_applied[self._vp] = d
        self._mj_step(self.model, self.data, self._substeps(dt))
        unstable = instability_error(self.name, self._warnings, t0)
        if unstable is not None:
            raise unstable

    def extras(self) -> dict[str, float]:
        return {"arm": float(self.data.qpos[self._qa]), "arm_dot": float(self.data.qvel[self._va])}

    def compiled(self) -> None:
        return None

    def compiled_mujoco(self, dt: float) -> None:
        return None

    @property
    def gain_sign(self) -> int:
        return FurutaODE(self.params).gain_sign


def _build_ode(cfg: PlantConfig, model_path: Path) -> Plant:
    if isinstance(cfg, FurutaMujocoConfig):
        # the ODE of a MuJoCo scenario is the compiled model's: one machine, two backends
        return DOMAIN.ode_of(_build_mujoco(cfg, model_path))
    return FurutaODE(FurutaParams())


def _build_mujoco(cfg: PlantConfig, model_path: Path) -> Plant:
    mj = cfg if isinstance(cfg, FurutaMujocoConfig) else FurutaMujocoConfig(
        kind="furuta_mujoco", x0=cfg.x0, state_bound=cfg.state_bound)
    return MujocoFuruta(model_path, mj.arm_joint, mj.pendulum_joint, mj.actuator,
                        mj.timestep or None,
                        mj.pendulum_damping if mj.pendulum_damping >= 0.0 else None)


# -- drawing ------------------------------------------------------------------------------
def _quat_z(angle: np.ndarray) -> np.ndarray:
    z = np.zeros_like(angle)
    return np.column_stack([z, z, np.sin(0.5 * angle), np.cos(0.5 * angle)])


def _quat_x(angle: np.ndarray) -> np.ndarray:
    z = np.zeros_like(angle)
    return np.column_stack([np.sin(0.5 * angle), z, z, np.cos(0.5 * angle)])


@dataclass(frozen=True)
class FurutaDrawing(Drawing):
    """The QUBE seen from its front: base, the arm turning about z, the pendulum about
    the arm (entity ``world/arm/pendulum``, so Rerun composes the two rotations)."""

    arm_length: float
    pendulum_length: float
    arm_height: float = 0.16
    title = "Furuta pendulum"

    def document(self) -> dict[str, Any]:
        return {"arm_length": self.arm_length, "pendulum_length": self.pendulum_length}

    def log_static(self, rec: Any, world: str, shade: Callable[[tuple], tuple]) -> None:
        import rerun as rr

        rec.log(world, rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        rec.log(f"{world}/base", rr.Boxes3D(half_sizes=[[0.051, 0.051, 0.051]],
                                            centers=[[0.0, 0.0, 0.051]],
                                            colors=[shade((30, 30, 36))],
                                            fill_mode=rr.components.FillMode.Solid), static=True)
        # the riser up to the arm's hinge, the arm along its +x, the pendulum along its +z
        # (thicker than the rig's rods, so they read at the view's distance)
        rec.log(f"{world}/riser", rr.Capsules3D(
            lengths=[self.arm_height - 0.102], radii=[0.02], translations=[[0.0, 0.0, 0.102]],
            colors=[shade((30, 30, 36))]), static=True)
        rec.log(f"{world}/arm", rr.Capsules3D(
            lengths=[self.arm_length], radii=[0.006], colors=[shade((178, 184, 191))],
            rotation_axis_angles=[rr.RotationAxisAngle(axis=[0.0, 1.0, 0.0], degrees=90.0)]),
            static=True)
        rec.log(f"{world}/arm/pendulum", rr.Capsules3D(
            lengths=[self.pendulum_length], radii=[0.005], colors=[shade((245, 158, 46))]),
            static=True)

    def log_frames(self, rec: Any, world: str, times: Any, x: np.ndarray,
                   extras: dict[str, np.ndarray]) -> None:
        import rerun as rr

        pendulum = np.asarray(x[:, 0], dtype=np.float64)
        arm = np.asarray(extras.get("arm", np.zeros_like(pendulum)), dtype=np.float64)
        n = pendulum.size
        rec.send_columns(f"{world}/arm", indexes=[times], columns=rr.Transform3D.columns(
            translation=np.tile([0.0, 0.0, self.arm_height], (n, 1)), quaternion=_quat_z(arm)))
        rec.send_columns(f"{world}/arm/pendulum", indexes=[times], columns=rr.Transform3D.columns(
            translation=np.tile([self.arm_length, 0.0, 0.0], (n, 1)),
            quaternion=_quat_x(pendulum)))

    def log_bounds(self, rec: Any, world: str, bounds: Sequence["Bound"],
                   shade: Callable[[tuple], tuple]) -> None:
        """The pendulum's bound (the fall angle) as two red rays from its pivot, in the
        plane it swings in (they turn with the arm); a limited arm's range as two red rays
        from the base."""
        import rerun as rr

        red = shade(END_COLOR)
        for bound in bounds:
            ends = [v for v in (bound.lo, bound.hi) if math.isfinite(v)]
            if bound.index == 1 and ends:  # the pendulum about the arm's tip (+x of the arm)
                r = self.pendulum_length
                tips = [[0.0, -r * math.sin(a), r * math.cos(a)] for a in ends]
                rec.log(f"{world}/arm/bounds", rr.Transform3D(translation=[self.arm_length, 0.0, 0.0]),
                        static=True)
                rec.log(f"{world}/arm/bounds", rr.LineStrips3D(
                    [[[0.0, 0.0, 0.0], tip] for tip in tips], colors=[red], radii=[0.0015]), static=True)
                high = max(tips, key=lambda tip: tip[2])
                rec.log(f"{world}/arm/bounds/label", rr.Points3D(
                    [[high[0], high[1], high[2] + 0.02]], colors=[red], radii=[0.002],
                    labels=[bound_text(bound)], show_labels=True), static=True)
            elif bound.index == 0 and ends:  # the arm about z
                r = 1.2 * self.arm_length
                tips = [[r * math.cos(a), r * math.sin(a), self.arm_height] for a in ends]
                rec.log(f"{world}/arm_bounds", rr.LineStrips3D(
                    [[[0.0, 0.0, self.arm_height], tip] for tip in tips], colors=[red], radii=[0.0015]),
                    static=True)
                rec.log(f"{world}/arm_bounds/label", rr.Points3D(
                    tips[-1:], colors=[red], radii=[0.002], labels=[bound_text(bound)],
                    show_labels=True), static=True)

    end_position = (0.0, 0.0, 0.32)

    def view(self, origin: str, suffix: str = "") -> Any:
        import rerun.blueprint as rrb

        return rrb.Spatial3DView(
            origin=origin, name=f"Furuta pendulum{suffix}",
            # close enough that the 8.5 cm arm and the 13 cm pendulum fill the view
            eye_controls=rrb.EyeControls3D(position=[0.24, -0.30, 0.27],
                                           look_target=[0.03, 0.0, 0.17], eye_up=[0.0, 0.0, 1.0]))


# -- the domain ---------------------------------------------------------------------------
@register_jitable
def view_accel_of(machine: FurutaMachine, s: np.ndarray, t: float, x: np.ndarray, u: float,
                  d: float) -> float:
    """pendulum'' over the view ``[pendulum, pendulum']`` with the arm at rest (``s``: a
    work array of the full state)."""
    s[0], s[1], s[2], s[3] = 0.0, x[0], 0.0, x[1]
    return machine_accelerations(machine, s, u, d)[1]


class FurutaView(NamedTuple):
    """The controllers' model of the view (:class:`~tspend.plants.domain.PlantModel`), as
    compiled code knows it; ``s`` is its work array."""

    machine: FurutaMachine
    s: np.ndarray

    def accel(self, t: float, x: np.ndarray, u: float, d: float) -> float:
        return view_accel_of(self.machine, self.s, t, x, u, d)


@register_jitable
def _compiled_view_accel(model: FurutaView, t: float, x: np.ndarray, u: float,
                         d: float) -> float:
    return view_accel_of(model.machine, model.s, t, x, u, d)


COMPILED_VIEW_ACCEL[FurutaView] = _compiled_view_accel


class FurutaDomain(Domain):
    """The rotary inverted pendulum: the arm's motor balances the pendulum on the arm."""

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

    def model_file(self, cfg: PlantConfig) -> str:
        return cfg.model if isinstance(cfg, FurutaMujocoConfig) else self.default_model

    def params_of_scenario(self, scenario: "Scenario") -> FurutaParams:
        plant = self.build(scenario)
        return plant.params  # type: ignore[attr-defined]

    def plant_model(self, scenario: "Scenario") -> PlantModel:
        """pendulum'' over the view with the arm at rest (the arm's motion enters only
        through back-EMF and coupling, which a model of the view leaves out); affine in u
        inside the amplifier's range."""
        view = FurutaView(self.params_of_scenario(scenario).machine(), np.zeros(4))
        # sliding mode's k: the arm's reaction and back-EMF left out of the view's model
        # are of the order of the upright's instability, ~100 rad/s^2 at 0.1 rad
        return PlantModel(scenario.plant.kind, 2, view.accel, affine_in_u=True,
                          x_op=(0.0, 0.0), switching_gain=20.0, compiled=view)

    def full_model(self, scenario: "Scenario") -> FullModel:
        """The Furuta ODE over ``[arm, pendulum, arm_dot, pendulum_dot]`` (the plant's
        joint names), from :func:`~tspend.plants.furuta_physics.accelerations_factory`
        (over CasADi with the identity clip: the MPC bounds u itself); the energy is
        :func:`~tspend.plants.furuta_physics.pendulum_energy`."""
        plant = self.build(scenario)
        params: FurutaParams = plant.params  # type: ignore[attr-defined]
        machine = params.machine()

        def factory(sin, cos, tanh):
            if sin is math.sin:
                accel = machine_accelerations
            else:
                accel = accelerations_factory(sin, cos, tanh, clip=lambda v, lo, hi: v)[2]

            def q_dd(s, u):
                return accel(machine, s, u, 0.0)

            return q_dd

        return FullModel(domain=self.name, state_names=tuple(plant.state_names),
                         accel_factory=factory,
                         energy=lambda s: pendulum_energy(machine, float(s[1]), float(s[3])),
                         pole=1, actuated=0, angles=(True, True, False, False),
                         parameters=dict(params.__dict__), machine=machine,
                         accel_unit="rad/s^2")

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
        """The model read back as the Furuta ODE's parameters, with the upright's
        linearisation's open-loop poles."""
        plant = MujocoFuruta(model_path)
        departures = plant.departures()
        facts: dict[str, Any] = {"domain": self.name, "joints": list(plant.state_names[:2]),
                                 "actuator": plant.actuator, "timestep": plant.timestep}
        if not departures:
            p = plant.params
            facts.update({k: (list(v) if isinstance(v, tuple) else v)
                          for k, v in p.__dict__.items()})
            A, _ = linearize(p)
            facts["upright_poles"] = sorted(float(e.real) for e in np.linalg.eigvals(A))
        return facts, departures

    def linearisation(self, scenario: "Scenario") -> tuple[np.ndarray, np.ndarray]:
        return linearize(self.params_of_scenario(scenario))

    def jacobians(self, plant: Plant, at: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """:func:`~tspend.plants.furuta_physics.linearize` at rest; None elsewhere."""
        if np.any(at[2:] != 0.0):
            return None
        return linearize(plant.params, pendulum=float(at[1]),  # type: ignore[attr-defined]
                         arm=float(at[0]))

    def drawing(self, plant: Plant, scenario: "Scenario") -> Drawing | None:
        p: FurutaParams = plant.params  # type: ignore[attr-defined]
        return FurutaDrawing(arm_length=float(np.linalg.norm(p.pivot)),
                             pendulum_length=2.0 * float(np.linalg.norm(p.pendulum_com)))

    def chirp_amplitude(self, plant: Plant) -> float:
        """3 V: a third of the amplifier's range, enough to throw the pendulum over."""
        return 3.0

    def ode_of(self, plant: Plant) -> Plant:
        return FurutaODE(plant.params, plant.arm_joint,  # type: ignore[attr-defined]
                         plant.pendulum_joint)  # type: ignore[attr-defined]


#: the Furuta domain
DOMAIN = FurutaDomain()
