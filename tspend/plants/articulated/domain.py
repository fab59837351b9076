"""The articulated-pendulum domain: any hinge/slide MJCF, its equations derived from the model.

A machine is an MJCF and a scenario (docs/machines.md): the double and triple cart-pole,
the acrobot, the pendubot, the reaction wheel, the rotary double pendulum, or a model of
one's own.  The scenario's ``[plant]`` names the model (``kind = "articulated_mujoco"``
or ``"articulated_ode"``); everything else comes from the compiled model
(:class:`.machine.Machine`): the state ``[q, q']`` named after the joints, the input
``u`` of one actuator (its range and unit), the equations (:mod:`.derive`), the joints'
roles and so the default task (every pole within the fall angle of upright, the rail's
range), and the drawing (the model's own geoms, posed by MuJoCo's kinematics).

Both plants share the state's names; ``d`` is a generalised force on the tracked pole's
joint (times ``d_scale``, 1 here; the MuJoCo cart-pole's ``-m l / (M + m)``).  The view the paper's controllers see is ``[pole, pole']`` of the first pole.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

import numpy as np
from numba.extending import register_jitable

from tspend.config import PlantConfig
from tspend.plants.drawing.model import ModelDrawing
from tspend.runtime.errors import ScenarioError
from tspend.plants.analytic import COMPILED_RHS, AnalyticPlant, CompiledPlant, rk4_work
from tspend.plants.articulated.machine import Machine, load_machine
from tspend.plants.base import InputInfo, JointInfo, MachinePlant, Plant, TaskDefaults, read_as
from tspend.plants.domain import (COMPILED_VIEW_ACCEL, FULL_STATE, SYMBOLIC, VIEW_MODEL, Backend,
    Domain, FullModel, PlantLabels, PlantModel, Quantity)
from tspend.plants.mujoco_plant import MujocoPlant
from tspend.plants.articulated.derive import jax_function_at
import tspend.runtime.xp as xp
from tspend.runtime.law import Slots, mark_law, with_jax_form

if TYPE_CHECKING:
    from tspend.config import Scenario

__all__ = ["ArticulatedConfig", "ArticulatedODE", "ArticulatedMujoco", "ArticulatedDomain", "pumped_full_model",
           "DOMAIN"]

#: what ``plant.integrator`` takes on every MuJoCo machine ("" keeps the model's)
#: slip velocity of the smooth dry friction F tanh(v / v_s) of the ODE twin, m/s or rad/s
DRY_FRICTION_SLIP = 1e-3

INTEGRATOR_CHOICES = ("", "RK4", "Euler", "implicit", "implicitfast")

#: the fall angle of every pole by default: a pole past the horizontal has fallen
FALL_ANGLE_RAD = math.pi / 2


@dataclass(frozen=True)
class ArticulatedConfig(PlantConfig):
    """A hinge/slide MJCF on either backend (the ODE is the compiled model's equations).

    ``x0`` is the view's initial state ``[pole, pole']`` (the first pole); ``q0`` the
    initial positions of every joint in the model's order (() = all 0; the view's pole
    takes ``x0[0]``); ``poles``: the joints the task keeps upright (() = every joint
    gravity acts on, docs/machines.md); ``actuator``: the one ``u`` drives ("" = the
    model's only one); ``timestep`` > 0 replaces the model's.  ``model_values``: what
    ``[randomize]`` drew of the model's numbers, written into it before it compiles
    (:mod:`.model_numbers`; not a ``[plant]`` key).
    """

    kind: str = "articulated_mujoco"
    x0: tuple[float, ...] = (0.1, 0.0)
    model: str = "models/double_cartpole.xml"
    q0: tuple[float, ...] = ()
    poles: tuple[str, ...] = field(default=(), metadata={"strings": True})
    actuator: str = ""
    timestep: float = field(default=0.0, metadata={"low": 0.0})
    #: MuJoCo's integrator of the model ("" keeps the model's; the ODE is stepped by RK4)
    integrator: str = field(default="", metadata={"choices": INTEGRATOR_CHOICES})
    model_values: tuple = field(default=(), metadata={"internal": True})


def _initial(machine: Machine, q0: tuple[float, ...], x0: np.ndarray, where: str) -> np.ndarray:
    nv = machine.nv
    if q0 and len(q0) != nv:
        raise ScenarioError(f"{where}: plant.q0 needs {nv} entries ({', '.join(machine.joint_names)}), "
                            f"got {len(q0)}")
    x0 = np.asarray(x0, dtype=float)
    if x0.shape != (2,):
        raise ScenarioError(f"{where}: plant.x0 needs 2 entries (the view: "
                            f"{machine.joint_names[machine.view_joint]} and its rate), got {x0.size}")
    s = np.zeros(2 * nv)
    if q0:
        s[:nv] = q0
    v = machine.view_joint
    s[v], s[nv + v] = x0[0], x0[1]
    return s


class _Named:
    """What both backends say alike of their machine (the state's names, units and joints:
    the one compiled model's, as :func:`.tree.read_tree` reads it)."""

    machine: Machine
    domain = "articulated"
    order = 2

    @cached_property
    def state_names(self) -> tuple[str, ...]:
        """Every joint's position (qpos), then every velocity (qvel), named after the joints."""
        return self.machine.state_names

    @property
    def state_units(self) -> tuple[str, ...]:
        return self.machine.state_units

    @property
    def joints(self) -> tuple[JointInfo, ...]:
        """Every joint of the compiled model, its range when ``limited``."""
        return tuple(JointInfo(j.name, j.kind, "m" if j.kind == "slide" else "rad", j.range)
                     for j in self.machine.tree.joints)

    @property
    def inputs(self) -> tuple[InputInfo, ...]:
        a = self.machine.actuator
        lo, hi = a.ctrlrange if a.ctrlrange is not None else (-math.inf, math.inf)
        m = self.machine
        unit = m.input_unit
        forced = unit != m.force_unit
        return (InputInfo(a.name, unit, lo, hi, m.force_unit if forced else "",
                          m.force_per_unit if forced else 1.0),)

    def default_task(self) -> TaskDefaults:
        m = self.machine
        v = m.joint_names[m.view_joint]
        poles = tuple(m.joint_names[j] for j in m.poles)
        return TaskDefaults(view=(v, f"{v}_dot"), fall_angle=FALL_ANGLE_RAD if poles else 0.0,
                            pole=poles[0] if poles else "", poles=poles)

    def parameters(self) -> dict[str, float]:
        return self.machine.parameters()

    def extras(self) -> dict[str, float]:
        s = self.full_state()
        view = set(self.default_task().view)
        return {n: float(v) for n, v in zip(self.state_names, s) if n not in view}

    def extras_index(self) -> np.ndarray:
        view = set(self.default_task().view)
        return np.array([i for i, n in enumerate(self.state_names) if n not in view], dtype=np.intp)

    @property
    def gain_sign(self) -> int:
        m = self.machine
        a = m.accelerations(np.zeros(2 * m.nv), 1.0)[m.view_joint]
        b = m.accelerations(np.zeros(2 * m.nv), 0.0)[m.view_joint]
        return 1 if a >= b else -1


class DerivedRHS(NamedTuple):
    """A derived machine as the compiled closed loop steps it: the C address of its
    generated ``rhs_c`` (a ctypes function, typed by its signature alone, so the loop's
    compiled code is one and cached whatever the machine) and its arrays."""

    fn: Any
    u: np.ndarray
    qfrc: np.ndarray
    p: np.ndarray
    M: np.ndarray
    r: np.ndarray
    actuator: int
    d_joint: int
    #: the generalised force on ``d_joint`` per unit d (1; the cart-pole's -m l / (M + m))
    d_scale: float
    #: each joint's smooth dry friction force (:func:`applied_forces`; 0: none)
    dry: np.ndarray


def _generated_rhs_jax(fn: Any, s: Any, u: Any, qfrc: Any, p: Any, M: Any, r: Any,
                       sdot: Any) -> Any:
    """:func:`call_rhs`'s JAX form: the same generated ``rhs`` source built over
    ``jax.numpy`` (:func:`.derive.jax_function_at`), on arrays it writes in place."""
    out = Slots.of(sdot)
    jax_function_at(fn)(s, u, qfrc, p, Slots.of(M), Slots.of(r), out)
    return out.frozen(),


@with_jax_form(_generated_rhs_jax)
@register_jitable
def call_rhs(fn: Any, s: np.ndarray, u: np.ndarray, qfrc: np.ndarray, p: np.ndarray,
             M: np.ndarray, r: np.ndarray, sdot: np.ndarray) -> tuple:
    """``(sdot,)``, ``sdot`` written by the generated ``rhs`` (equations (3) of :mod:`.derive`): its
    numba build called by the C address ``fn``; its JAX form evaluates the same source."""
    fn(s.ctypes.data, u.ctypes.data, qfrc.ctypes.data, p.ctypes.data, M.ctypes.data,
       r.ctypes.data, sdot.ctypes.data)
    return sdot,


def _generated_energy_jax(fn: Any, q: Any, qd: Any, p: Any, T: Any, V: Any) -> Any:
    """:func:`call_energy`'s JAX form (as :func:`_generated_rhs_jax`)."""
    T, V = Slots.of(T), Slots.of(V)
    jax_function_at(fn)(q, qd, p, T, V)
    return T[0] + V[0]


@with_jax_form(_generated_energy_jax)
@register_jitable
def call_energy(fn: Any, q: np.ndarray, qd: np.ndarray, p: np.ndarray, T: np.ndarray,
                V: np.ndarray) -> float:
    """``T + V`` of the generated ``energy`` ((1)-(2) of :mod:`.derive`), as :func:`call_rhs`."""
    fn(q.ctypes.data, qd.ctypes.data, p.ctypes.data, T.ctypes.data, V.ctypes.data)
    return T[0] + V[0]


@mark_law
@register_jitable
def applied_forces(qfrc: np.ndarray, s: np.ndarray, d_joint: int, d_scale: float, d: float,
                   dry: np.ndarray) -> tuple:
    """The generalised forces a derived ODE applies besides its equations, into ``qfrc``:
    ``d_scale d`` on joint ``d_joint``, and on each joint ``j`` with ``dry[j] > 0`` the
    smooth dry friction ``-dry[j] tanh(q'_j / v_s)`` (the cart-pole's ODE twin: MuJoCo's
    ``frictionloss`` is a soft constraint, this its smooth stand-in, as the hand-written
    cart-pole has it; every other machine leaves dry friction out, a named departure).
    One law (:mod:`tspend.runtime.law`) for the generic, the compiled loop and JAX;
    returns ``(qfrc,)`` (compiled code without numba's runtime returns an array it was
    given only inside a tuple)."""
    nv = qfrc.size
    for j in range(nv):
        f = d_scale * d if j == d_joint else 0.0
        qfrc = xp.put(qfrc, j, xp.where(dry[j] > 0.0,
                                        f - dry[j] * math.tanh(s[nv + j] / DRY_FRICTION_SLIP), f))
    return qfrc,


@mark_law
@register_jitable
def derived_rhs(m: DerivedRHS, t: float, s: np.ndarray, u: float, d: float,
                sdot: np.ndarray) -> tuple:
    """``(sdot,)``: ``s' = f(s, u)`` of the derived equations into ``sdot`` (as
    :meth:`Machine.rhs_into`)."""
    inputs = m.u
    for k in range(inputs.size):
        inputs = xp.put(inputs, k, u if k == m.actuator else 0.0)
    qfrc, = applied_forces(m.qfrc, s, m.d_joint, m.d_scale, d, m.dry)
    return call_rhs(m.fn, s, inputs, qfrc, m.p, m.M, m.r, sdot)


COMPILED_RHS[DerivedRHS] = derived_rhs


def derived_rhs_of(machine: Machine, d_joint: int, d_scale: float = 1.0,
                   dry: np.ndarray | None = None) -> DerivedRHS:
    """``machine``'s :class:`DerivedRHS`, ``d`` a generalised force ``d_scale d`` on joint
    ``d_joint``, ``dry`` each joint's smooth dry friction force (None: none)."""
    import ctypes

    fn = ctypes.CFUNCTYPE(None, *[ctypes.c_void_p] * 7)(machine.module.rhs_c.address)
    fn.argtypes, fn.restype = [ctypes.c_void_p] * 7, None
    nv = machine.nv
    return DerivedRHS(fn, np.zeros(len(machine.tree.actuators)), np.zeros(nv), machine.p,
                      np.zeros(nv * nv), np.zeros(nv), machine.actuator_index, d_joint,
                      float(d_scale), np.zeros(nv) if dry is None else np.array(dry, dtype=float))


class ArticulatedODE(_Named, AnalyticPlant):
    """The derived equations (3) of :mod:`.derive`, stepped by the shared RK4."""

    name = "articulated_ode"

    def __init__(self, machine: Machine, q0: tuple[float, ...] = ()) -> None:
        AnalyticPlant.__init__(self, lambda t, s, u, d: 0.0, 2, "articulated_ode",
                               domain="articulated")
        self.machine, self.q0 = machine, tuple(q0)
        self.s = np.zeros(2 * machine.nv)
        self._work = rk4_work(self.s.size)
        self._full_order = np.arange(self.s.size, dtype=np.intp)
        self._d_joint = machine.view_joint
        #: the generalised force on ``_d_joint`` per unit d, each joint's dry friction
        #: force (:func:`applied_forces`)
        self._d_scale = 1.0
        self._dry = np.zeros(machine.nv)
        self._qfrc = np.zeros(machine.nv)

    def reset(self, x0: np.ndarray) -> None:
        self.s[:] = _initial(self.machine, self.q0, x0, self.machine.where)
        self._clock[0] = 0.0

    def full_state(self) -> np.ndarray:
        return self.s.copy()

    def rhs_into(self, t: float, s: np.ndarray, u: float, d: float, sdot: np.ndarray) -> None:
        applied_forces(self._qfrc, s, self._d_joint, self._d_scale, d, self._dry)
        self.machine.rhs_forced(s, u, self._qfrc, sdot)

    def _rhs_params(self) -> Any:
        return self

    def compiled(self) -> CompiledPlant:
        """The plant for the compiled closed loop: RK4 over the generated ``rhs_c`` by its C
        address (:class:`DerivedRHS`; a type of a generated module would not do: numba
        caches the loop with every parameter type, and the next process loading that cache
        could not import a module of the derivation cache)."""
        return CompiledPlant(derived_rhs_of(self.machine, self._d_joint, self._d_scale,
                                            self._dry), self.s, self._clock,
                             self._work, self._full_order)


class ArticulatedMujoco(_Named, MujocoPlant):
    """The MJCF stepped by MuJoCo (:class:`~tspend.plants.mujoco_plant.MujocoPlant`): ``u``
    is the actuator's ctrl, ``d`` the generalised force on the tracked pole's joint."""

    name = "articulated_mujoco"

    def __init__(self, machine: Machine, q0: tuple[float, ...] = (), d_scale: float = 1.0) -> None:
        self.machine, self.q0 = machine, tuple(q0)
        # the tree's actuators and joints are MuJoCo's, in its order (:func:`.tree.read_tree`)
        self._attach(machine.model, machine.where, machine.actuator_index, machine.view_joint,
                     d_scale)
        self.reset(np.zeros(2))

    def departures(self, dt: float | None = None) -> list[str]:
        out = list(self.machine.tree.departures)
        if self.machine.tree.integrator != "RK4":
            out.append(f"integrator {self.machine.tree.integrator}: the ODE is stepped by RK4")
        if dt is not None and abs(round(dt / self._ts) * self._ts - dt) > 1e-9 * dt:
            out.append(f"dt = {dt:g} s is not a whole multiple of the timestep {self._ts:g} s")
        return out

    def _place(self, x0: np.ndarray) -> None:
        s = _initial(self.machine, self.q0, x0, self.machine.where)
        nv = self.machine.nv
        self.data.qpos[:] = s[:nv]
        self.data.qvel[:] = s[nv:]


# -- the domain ---------------------------------------------------------------------------
def _machine_of(cfg: ArticulatedConfig, model_path: Path) -> Machine:
    return load_machine(model_path, cfg.timestep, cfg.actuator, tuple(cfg.poles),
                        tuple(cfg.model_values), cfg.integrator)


def _build_ode(cfg: PlantConfig, model_path: Path) -> Plant:
    assert isinstance(cfg, ArticulatedConfig)
    return ArticulatedODE(_machine_of(cfg, model_path), tuple(cfg.q0))


def _build_mujoco(cfg: PlantConfig, model_path: Path) -> Plant:
    assert isinstance(cfg, ArticulatedConfig)
    return ArticulatedMujoco(_machine_of(cfg, model_path), tuple(cfg.q0))


class DerivedFull(NamedTuple):
    """A derived machine as compiled full-state controllers (the swing-up) ask for it
    (:func:`derived_full_accel`, :func:`derived_pole_energy`): ``q''(s, u)`` and the energy of the pole ``pole`` with every other joint at rest at 0
    (the machine's ``T + V`` there, less its value upright at rest ``V0``), through the
    generated ``rhs_c`` and ``energy_c`` by their C addresses."""

    rhs: DerivedRHS
    energy_fn: Any
    pole: int
    s: np.ndarray
    sdot: np.ndarray
    T: np.ndarray
    V: np.ndarray
    pad: np.ndarray
    V0: float


@mark_law
@register_jitable
def derived_full_accel(m: DerivedFull, s: np.ndarray, u: float) -> tuple:
    """``q''(s, u)`` padded with zeros to 6 entries (the derivation's most joints): a
    tuple, as compiled code without allocation can return one."""
    sdot, = derived_rhs(m.rhs, 0.0, s, u, 0.0, m.sdot)
    nv = m.s.size // 2
    a = m.pad
    for i in range(6):
        a = xp.put(a, i, sdot[nv + i] if i < nv else 0.0)
    return a[0], a[1], a[2], a[3], a[4], a[5]


@mark_law
@register_jitable
def derived_pole_energy(m: DerivedFull, s: np.ndarray) -> float:
    nv = m.s.size // 2
    at = m.s
    for k in range(2 * nv):
        at = xp.put(at, k, s[k] if k == m.pole or k == nv + m.pole else 0.0)
    return call_energy(m.energy_fn, at, at[nv:], m.rhs.p, m.T, m.V) - m.V0


def derived_full_of(machine: Machine, pole: int) -> DerivedFull:
    """``machine``'s :class:`DerivedFull` for its pole ``pole``."""
    import ctypes

    fn = ctypes.CFUNCTYPE(None, *[ctypes.c_void_p] * 5)(machine.module.energy_c.address)
    fn.argtypes, fn.restype = [ctypes.c_void_p] * 5, None
    nv = machine.nv
    full = DerivedFull(derived_rhs_of(machine, machine.view_joint), fn, pole, np.zeros(2 * nv),
                       np.zeros(2 * nv), np.zeros(1), np.zeros(1), np.zeros(6), 0.0)
    return full._replace(V0=derived_pole_energy(full, np.zeros(2 * nv)))


def pumped_full_model(domain: str, plant: Plant, m: Machine, parameters: dict[str, float],
                      clips: bool = False) -> FullModel:
    """The :class:`FullModel` of a two-joint machine whose one pole's energy a swing-up
    pumps (the cart-pole's, the Furuta's): numbers through the compiled module
    (:func:`derived_full_accel`), CasADi through the derivation (``clips``: with MuJoCo's
    clips of ctrl and force), the energy the pole's with the other joint at rest at 0."""
    full = derived_full_of(m, m.view_joint)

    def factory(sin, cos, tanh):
        if sin is math.sin:
            return lambda s, u: derived_full_accel(full, np.asarray(s, dtype=float), u)[:2]

        def q_dd(s, u):
            a = m.symbolic_accel(s, u, clips=clips)
            return a[0], a[1]

        return q_dd

    slide = m.tree.joints[m.actuated].kind == "slide"
    return FullModel(domain=domain, state_names=tuple(plant.state_names), accel_factory=factory,
                     energy=lambda s: derived_pole_energy(full, np.asarray(s, dtype=float)),
                     pole=m.view_joint, actuated=m.actuated,
                     angles=tuple(j.kind == "hinge" for j in m.tree.joints) + (False,) * 2,
                     parameters=parameters, machine=full, accel_unit="m/s^2" if slide else "rad/s^2")


class DerivedView(NamedTuple):
    """The paper's controllers' model of the view: the tracked pole's acceleration with
    every other joint at rest (as :class:`~tspend.plants.domain.PlantModel` asks), from
    the derived equations through :class:`DerivedRHS`, for Python and compiled code."""

    rhs: DerivedRHS
    s: np.ndarray
    sdot: np.ndarray
    joint: int

    def accel(self, t: float, x: np.ndarray, u: float, d: float) -> float:
        return derived_view_accel(self, t, x, u, d)


@mark_law
@register_jitable
def derived_view_accel(v: DerivedView, t: float, x: np.ndarray, u: float, d: float) -> float:
    nv = v.s.size // 2
    at = v.s
    for k in range(2 * nv):
        at = xp.put(at, k, 0.0)
    at = xp.put(at, v.joint, x[0])
    at = xp.put(at, nv + v.joint, x[1])
    sdot, = derived_rhs(v.rhs, t, at, u, d, v.sdot)
    return sdot[nv + v.joint]


COMPILED_VIEW_ACCEL[DerivedView] = derived_view_accel


def derived_view(machine: Machine, d_scale: float = 1.0) -> DerivedView:
    """``machine``'s view model (its first pole's, ``d_scale d`` on that joint)."""
    nv = machine.nv
    return DerivedView(derived_rhs_of(machine, machine.view_joint, d_scale), np.zeros(2 * nv),
                       np.zeros(2 * nv), machine.view_joint)


class ArticulatedDomain(Domain):
    """Any kinematic tree of hinge and slide joints, from its MJCF (module docstring)."""

    name = "articulated"
    kinds = {"articulated_ode": Backend(ArticulatedConfig, _build_ode),
             "articulated_mujoco": Backend(ArticulatedConfig, _build_mujoco, mujoco=True)}
    labels = PlantLabels(
        states=(Quantity("q", "rad", "the tracked pole's angle"),
                Quantity("q'", "rad/s", "the tracked pole's rate")),
        control=Quantity("u", "", "the actuator's input"), extras={},
        disturbance=Quantity("d", "", "generalised force on the tracked pole's joint"))
    #: the view's two entries stand for the tracked pole's angle and rate (each plant names
    #: them after its model's joint: :meth:`view_names`)
    task = TaskDefaults(view=("pole", "pole_dot"), fall_angle=FALL_ANGLE_RAD)
    default_model = ArticulatedConfig.model
    provides = frozenset({VIEW_MODEL, FULL_STATE, SYMBOLIC})
    derives_equations = True

    def model_file(self, cfg: PlantConfig) -> str:
        return cfg.model if isinstance(cfg, ArticulatedConfig) else self.default_model

    def view_names(self, plant: Plant) -> tuple[str, ...]:
        return plant.default_task().view

    def machine(self, scenario: "Scenario") -> Machine:
        return read_as(self.build(scenario), MachinePlant).machine

    def nominal_values(self, scenario: "Scenario") -> dict[str, float]:
        """The compiled model's ``BODY.mass``, ``JOINT.damping``, ``JOINT.armature``
        (:mod:`.model_numbers`): what a ``[randomize]`` entry may name, and its nominal."""
        from tspend.plants.articulated.model_numbers import model_values

        return model_values(self.machine(scenario).model)

    def plant_model(self, scenario: "Scenario", machine: Plant) -> PlantModel:
        """The tracked pole's acceleration with every other joint at rest; sliding mode's
        k is of the order of the upright's instability, what that model leaves out (the
        Furuta's arm reaction and back-EMF: ~100 rad/s^2 at 0.1 rad)."""
        view = derived_view(read_as(machine, MachinePlant).machine)
        return PlantModel(scenario.plant.kind, 2, view.accel, affine_in_u=True,
                          x_op=(0.0, 0.0), switching_gain=20.0, compiled=view)

    def full_model(self, scenario: "Scenario", machine: Plant) -> FullModel:
        """The derived equations over ``[q, q']`` (the joints' names): numbers through the
        compiled module, CasADi through the derivation (no clips: MPC bounds u)."""
        m = read_as(machine, MachinePlant).machine
        nv = m.nv

        def factory(sin, cos, tanh):
            if sin is math.sin:
                return lambda s, u: tuple(m.accelerations(np.asarray(s, dtype=float), float(u)))

            def q_dd(s, u):
                a = m.symbolic_accel(s, u)
                return tuple(a[i] for i in range(nv))

            return q_dd

        angles = tuple(j.kind == "hinge" for j in m.tree.joints) + (False,) * nv
        poles = m.poles
        return FullModel(domain=self.name, state_names=m.state_names, accel_factory=factory,
                         energy=m.energy, pole=poles[0] if poles else m.actuated,
                         actuated=m.actuated, angles=angles, parameters=m.parameters(),
                         machine=None, poles=poles,
                         accel_unit="m/s^2" if m.tree.joints[m.actuated].kind == "slide" else "rad/s^2")

    def linearisation(self, scenario: "Scenario", machine: Plant) -> tuple[np.ndarray, np.ndarray]:
        return read_as(machine, MachinePlant).machine.linearisation()

    def jacobians(self, plant: Plant, at: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        return read_as(plant, MachinePlant).machine.linearisation(at)

    def drawing(self, plant: Plant, scenario: "Scenario") -> ModelDrawing:
        m = read_as(plant, MachinePlant).machine
        return ModelDrawing(m, plant.default_task().view, Path(m.where).stem.replace("_", " "))

    def chirp_amplitude(self, plant: Plant) -> float:
        a = read_as(plant, MachinePlant).machine.actuator
        if a.ctrlrange is not None:
            return 0.3 * min(abs(a.ctrlrange[0]), abs(a.ctrlrange[1]))
        return 1.0

    def ode_of(self, plant: Plant) -> Plant:
        own = read_as(plant, MachinePlant)
        return ArticulatedODE(own.machine, own.q0)

    def fits_mjcf(self, joint_types: tuple[str, ...]) -> bool:
        return bool(joint_types) and all(t in ("hinge", "slide") for t in joint_types) \
            and len(joint_types) <= 6

    def inspect(self, model_path: str, names: dict[str, str] | None = None,
                dt: float | None = None) -> tuple[dict[str, Any], list[str]]:
        """The model's joints with their roles, the actuator, the upright's open-loop poles
        and controllability."""
        m = load_machine(model_path)
        plant = ArticulatedMujoco(m)
        facts: dict[str, Any] = {
            "domain": self.name,
            "joints": {j.name: {"type": j.kind, "role": r,
                                **({"range": list(j.range)} if j.range else {})}
                       for j, r in zip(m.tree.joints, m.roles)},
            "actuator": {"name": m.actuator.name, "joint": m.joint_names[m.actuated],
                         "unit": m.input_unit,
                         **({"ctrlrange": list(m.actuator.ctrlrange)} if m.actuator.ctrlrange else {})},
            "tracked": m.joint_names[m.view_joint], "timestep": plant.timestep,
            "integrator": m.tree.integrator,
            "bodies": {b.name: {"mass": b.mass} for b in m.tree.bodies},
        }
        A, B = m.linearisation()
        facts["upright_poles"] = sorted((complex(e) for e in np.linalg.eigvals(A)),
                                        key=lambda e: (e.real, e.imag))
        facts["upright_poles"] = [round(e.real, 6) if abs(e.imag) < 1e-12 else
                                  f"{e.real:.6g}{e.imag:+.6g}j" for e in facts["upright_poles"]]
        n = A.shape[0]
        C = np.hstack([np.linalg.matrix_power(A, k) @ B for k in range(n)])
        facts["controllable"] = bool(np.linalg.matrix_rank(C, tol=1e-9 * max(1.0, np.abs(C).max())) == n)
        return facts, plant.departures(dt)


#: the articulated domain
DOMAIN = ArticulatedDomain()
