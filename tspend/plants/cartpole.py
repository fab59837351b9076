"""The cart-pole domain: an articulated machine (docs/articulated.md) with the paper's names.

A cart-pole is its MJCF (``models/cartpole.xml`` by default) read and derived like every
other machine (:class:`~tspend.plants.articulated.machine.Machine`): one MuJoCo plant
(:class:`~tspend.plants.mujoco_plant.MujocoCartPole`), one derived model (nominal for the
controllers, the joints' damping and dry friction left out), one linearisation (CasADi's
derivatives of the derived equations), one ODE twin (:class:`DerivedCartPoleODE`: the
derived equations with the model's damping and its ``frictionloss`` as the smooth
``F tanh(v / v_s)``), one drawing and one reader of the compiled model
(:mod:`tspend.plants.mjcf`).  A model the derivation refuses is refused in one line naming
what to change.

Two kinds: ``cartpole_mujoco`` steps the MJCF in MuJoCo; ``cartpole_ode`` (the paper's
Example 3, ``ex3_pendulum_ode``) integrates the derived equations of the same MJCF with
every ``[plant]`` number (M, m, l, J, g, gear, damping, friction) written into the model
and checked on the compiled one.  The paper's own equation is
:func:`tspend.plants.analytic.cartpole_accel`; the hand-written (C1)-(C2) are the grey-box
model ``tspend identify`` fits and the test oracle (:mod:`tspend.studies.cartpole_greybox`).

This module holds the scenario's ``[plant]`` configuration, the roles of the MJCF's joints
(``slide`` = the cart, ``hinge`` = the pole), labels and units and the default task (view
``hinge``, ``hinge_dot``; fall angle pi/2); it is drawn as every machine is, from its own
geoms (:class:`~tspend.drawing.model.ModelDrawing`, with its rail).
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from tspend.config import PlantConfig
from tspend.drawing.model import ModelDrawing
from tspend.effects import EffectsPlant
from tspend.plants.articulated.domain import ArticulatedODE, derived_view, pumped_full_model
from tspend.plants.articulated.machine import Machine
from tspend.plants.articulated.derive import parameter_table
from tspend.plants.articulated.tree import read_tree
from tspend.plants.base import Plant, TaskDefaults
from tspend.plants.mjcf import OVERRIDABLE, CartPoleParams
from tspend.plants.domain import (CART_CENTRING, CHIRP_F0_HZ, FULL_STATE,
    PARAMETER_CHANGE, PUMPED_ENERGY, SYMBOLIC, VIEW_MODEL, Backend, Domain,
    FullModel, PlantLabels, PlantModel, Quantity)

if TYPE_CHECKING:
    from tspend.config import Scenario
    from tspend.task import Task

__all__ = ["CartPoleParams", "CartPoleConfig", "MujocoCartPoleConfig", "DerivedCartPoleODE",
           "CartPoleDomain", "DOMAIN", "cartpole_machine", "nominal_machine"]


# -- the scenario's [plant] table, on either backend -------------------------------------

def _positive(**more) -> dict:
    return {"low": 0.0, "strict": True, **more}


def _at_least_zero(**more) -> dict:
    return {"low": 0.0, **more}


def _own_if_zero() -> dict:
    """A key whose 0 stands for the machine's own value (``own``): >= 0 when set, but
    a ``[randomize]`` draw of it must be > 0 (a drawn 0 would not be the value drawn)."""
    return _at_least_zero(own=True)


@dataclass(frozen=True)
class CartPoleConfig(PlantConfig):
    """A cart-pole on either backend: the numbers written into its MJCF (the paper's
    Example 3 machine by default)."""

    M: float = field(default=10.0, metadata=_positive())
    m: float = field(default=1.0, metadata=_positive())
    l: float = field(default=3.0, metadata=_positive())
    g: float = field(default=9.8, metadata=_at_least_zero())
    #: pole inertia about the pivot, kg m^2 (0 = the uniform rod's 4/3 m l^2)
    J: float = field(default=0.0, metadata=_own_if_zero())
    #: viscous damping (N s/m, N m s/rad) and dry friction (N, N m) at cart and hinge
    cart_damping: float = field(default=0.0, metadata=_at_least_zero())
    hinge_damping: float = field(default=0.0, metadata=_at_least_zero())
    cart_friction: float = field(default=0.0, metadata=_at_least_zero())
    hinge_friction: float = field(default=0.0, metadata=_at_least_zero())
    #: actuator gain, N of cart force per unit of u at rest (0 = the model's own gear x
    #: gain; the ODE's 1)
    gear: float = field(default=0.0, metadata=_own_if_zero())


@dataclass(frozen=True)
class MujocoCartPoleConfig(CartPoleConfig):
    """A cart-pole MJCF stepped by MuJoCo, as it is: its masses, geometry, actuator and
    limits are the model's own.

    ``M``, ``m``, ``l``, ``J`` and ``g`` are *overrides* (docs/third-party-models.md):
    0, the default, keeps the model's value; a positive value is written into the model
    before it compiles and verified on the compiled model (J: the uniform rod's 4/3 m l^2
    when m or l is set and J is not).  The damping and friction keys likewise replace the
    model's joint values when not 0.
    """

    M: float = field(default=0.0, metadata=_own_if_zero())
    m: float = field(default=0.0, metadata=_own_if_zero())
    l: float = field(default=0.0, metadata=_own_if_zero())
    g: float = field(default=0.0, metadata=_own_if_zero())
    #: model file (relative to the cwd, the scenario or the project root) and its names
    model: str = "models/cartpole.xml"
    slide_joint: str = "slider"
    hinge_joint: str = "hinge"
    actuator: str = "force"
    #: "" keeps the model's integrator
    integrator: str = field(default="", metadata={"choices": ("", "RK4", "Euler", "implicit",
                                                              "implicitfast")})
    #: physics timestep, s (0 keeps the model's); dt must be a whole multiple of it
    timestep: float = field(default=0.0, metadata=_at_least_zero())
    #: false ignores the override keys M, m, l, J, g (the model's own numbers)
    override_inertials: bool = True

    def overrides(self) -> dict[str, float]:
        """The override keys set (name -> value): what the model is changed by."""
        if not self.override_inertials:
            return {}
        return {k: float(getattr(self, k)) for k in OVERRIDABLE if getattr(self, k) > 0.0}


# -- the derived equations of a MuJoCo cart-pole ----------------------------------------
def cartpole_machine(plant: Plant) -> Machine:
    """The articulated machine of a MuJoCo cart-pole ``plant``: its compiled (overridden)
    model read and derived (docs/articulated.md), the hinge its pole, ``u`` its actuator;
    the machine of a :class:`DerivedCartPoleODE` is its own.  ScenarioError (one line
    naming what to change) for a model the derivation refuses."""
    if isinstance(plant, EffectsPlant):
        plant = plant.inner
    return plant.machine  # type: ignore[attr-defined]


def nominal_machine(machine: Machine) -> Machine:
    """``machine`` as the controllers assume it: its joints' damping 0 (a copy; the
    derived equations have no dry friction), as :func:`_nominal` leaves a rig's friction
    out of the model's numbers."""
    nominal = copy.copy(machine)
    nominal.p = machine.p.copy()
    for i, name in enumerate(machine.parameter_names):
        if name.endswith(".damping"):
            nominal.p[i] = 0.0
    return nominal


class DerivedCartPoleODE(ArticulatedODE):
    """The ODE twin of a MuJoCo cart-pole: the equations derived from its compiled model
    (:class:`~tspend.plants.articulated.domain.ArticulatedODE`), ``d`` applied as MuJoCo's
    cart-pole applies it, the hinge torque ``-d m l / (M + m)``, and MuJoCo's soft dry
    friction (``frictionloss``) as the smooth ``F tanh(v / v_s)`` the hand-written ODE has
    (:func:`~tspend.plants.articulated.domain.applied_forces`; they agree in kind, a
    departure the cross-check names).  What it says of itself (inputs, joints, task,
    ``params``, the extras ``cart_pos``, ``cart_vel``) is the MuJoCo plant's, so both
    backends describe one machine."""

    def __init__(self, source: Plant, machine: Machine) -> None:
        ArticulatedODE.__init__(self, machine)
        self.name, self.domain = "cartpole_ode", "cartpole"
        self._source = source
        self._d_scale = self.params.disturbance_torque
        self._cart = next(i for i, j in enumerate(machine.tree.joints) if j.kind == "slide")
        # MuJoCo's frictionloss as the hand-written ODE has it, F tanh(v / v_s)
        self._dry[self._cart] = self.params.cart_friction
        self._dry[machine.view_joint] = self.params.hinge_friction

    # the MuJoCo plant's: its CartPoleParams are the names the metrics show
    inputs = property(lambda self: self._source.inputs)
    joints = property(lambda self: self._source.joints)
    gain_sign = property(lambda self: self._source.gain_sign)
    params = property(lambda self: self._source.params)

    def default_task(self) -> TaskDefaults:
        return self._source.default_task()

    def parameters(self) -> dict[str, float]:
        return self.params.finite()

    def set_params(self, params: CartPoleParams) -> None:
        """Change M, m, l (J) while it runs (a payload picked up): written into the
        compiled model as the MuJoCo plant writes them, the derived parameter vector read
        again from it; the state is kept."""
        self._source.set_params(params)  # type: ignore[attr-defined]
        self.machine.p[:] = parameter_table(read_tree(self._source.mj_model()))[1]
        self._d_scale = self.params.disturbance_torque

    def extras(self) -> dict[str, float]:
        nv = self.machine.nv
        return {"cart_pos": float(self.s[self._cart]), "cart_vel": float(self.s[nv + self._cart])}

    def extras_index(self) -> np.ndarray:
        return np.array([self._cart, self.machine.nv + self._cart], dtype=np.intp)


def _nominal(params: CartPoleParams) -> CartPoleParams:
    """The rigid machine of ``params``: a nominal model leaves a rig's friction out."""
    return replace(params, cart_damping=0.0, hinge_damping=0.0, cart_friction=0.0,
                   hinge_friction=0.0)


def _build_mujoco(cfg: PlantConfig, model_path: Path) -> Plant:
    from tspend.plants.mujoco_plant import MujocoCartPole  # MuJoCo only when asked for

    assert isinstance(cfg, CartPoleConfig)
    unbounded = not isinstance(cfg, MujocoCartPoleConfig)
    if isinstance(cfg, MujocoCartPoleConfig):
        mj, overrides = cfg, cfg.overrides()
    else:
        # an ODE scenario on the MJCF (the paper's Example 3 by default): its machine is
        # explicit, every number written, u unbounded as the paper has it
        mj = MujocoCartPoleConfig(**{k: cfg.__dict__[k] for k in CartPoleConfig.__dataclass_fields__})
        overrides = {k: float(getattr(cfg, k)) for k in OVERRIDABLE}
    friction = {k: (mj.__dict__[k] or None) for k in
                ("cart_damping", "hinge_damping", "cart_friction", "hinge_friction")}
    plant = MujocoCartPole(model_path, slide_joint=mj.slide_joint, hinge_joint=mj.hinge_joint,
                           actuator=mj.actuator, overrides=overrides,
                           integrator=mj.integrator or None, timestep=mj.timestep or None,
                           gear=mj.gear or None,
                           task_defaults=DOMAIN.task, ctrl_unbounded=unbounded, **friction)
    # a cart-pole is an articulated machine: its equations (the controllers' models, the
    # ODE twin, the task check) are derived from the model, so a model that cannot be
    # derived is refused here, in one line naming what to change, not midway
    cartpole_machine(plant)
    return plant


def _build_ode(cfg: PlantConfig, model_path: Path) -> Plant:
    # the ODE is the compiled model's (masses, inertia, damping, gear and angle sign read
    # back), so both backends describe one machine
    return DOMAIN.ode_of(_build_mujoco(cfg, model_path))


# -- labels, drawing, task, model -------------------------------------------------------
LABELS = PlantLabels(
    states=(Quantity("theta", "rad", "pole angle"),
            Quantity("theta'", "rad/s", "pole angular velocity")),
    control=Quantity("u", "N", "force on the cart"),
    extras={"cart_pos": Quantity("x_c", "m", "cart position"),
            "cart_vel": Quantity("x_c'", "m/s", "cart velocity")},
    # the full state (slide, hinge, slide_dot, hinge_dot) whatever the MJCF calls its joints
    full_state=(Quantity("x_c", "m", "cart position", "cart_x"),
                Quantity("theta", "rad", "pole angle", "theta"),
                Quantity("x_c'", "m/s", "cart velocity", "cart_v"),
                Quantity("theta'", "rad/s", "pole angular velocity", "theta_dot")),
    # d_d enters (C1)'s numerator beside the force: a force (the hinge torque -d m l/(M+m))
    disturbance=Quantity("d", "N", "disturbance force"),
)

#: the cross-check's open-loop chirp: amplitude per kg of total mass
CHIRP_N_PER_KG = 100.0 / 11.0


class CartPoleDomain(Domain):
    """The cart-pole: its MJCF stepped by MuJoCo, or its derived equations integrated."""

    name = "cartpole"
    kinds = {"cartpole_ode": Backend(CartPoleConfig, _build_ode),
             "cartpole_mujoco": Backend(MujocoCartPoleConfig, _build_mujoco, mujoco=True)}
    labels = LABELS
    task = TaskDefaults(view=("hinge", "hinge_dot"), fall_angle=math.pi / 2, pole="hinge")
    default_model = MujocoCartPoleConfig.model
    rail_joint = "slider"
    provides = frozenset({VIEW_MODEL, FULL_STATE, SYMBOLIC, PARAMETER_CHANGE, CART_CENTRING,
                          PUMPED_ENERGY})

    def model_file(self, cfg: PlantConfig) -> str:
        return cfg.model if isinstance(cfg, MujocoCartPoleConfig) else self.default_model

    def nominal_values(self, scenario: "Scenario") -> dict[str, float]:
        """A MuJoCo cart-pole's keys left at 0 as its compiled model has them (``M`` the
        cart's mass, ``m``, ``l``, ``J`` the pole's, ``gear`` the force per unit u at
        rest, the joints' damping and friction loss); the ODE's ``J`` (the rod's) and
        ``gear`` (1)."""
        plant = self.build(scenario)
        if isinstance(scenario.plant, MujocoCartPoleConfig):
            f = plant.facts  # type: ignore[attr-defined]
            return {"M": f.cart_mass, "m": f.pole_mass, "l": f.pole_com,
                    "J": f.pole_inertia_pivot, "g": f.gravity, "gear": f.force_per_u,
                    "cart_damping": f.slide.damping, "hinge_damping": f.hinge.damping,
                    "cart_friction": f.slide.frictionloss,
                    "hinge_friction": f.hinge.frictionloss}
        p = plant.params  # type: ignore[attr-defined]
        return {"J": p.pole_inertia_pivot, "gear": p.force_per_u}

    def nominal_derived(self, scenario: "Scenario", plant: Plant) -> Machine:
        """The derived machine the controllers assume (:func:`nominal_machine` of
        :func:`cartpole_machine` of the nominal ``plant``)."""
        return nominal_machine(cartpole_machine(plant))

    def full_model(self, scenario: "Scenario", machine: Plant) -> FullModel:
        """The nominal machine over ``[slider, hinge, slider_dot, hinge_dot]`` (the plant's
        own joint names), with MuJoCo's clips of ctrl and force (:func:`pumped_full_model`)."""
        params = _nominal(machine.params)  # type: ignore[attr-defined]
        return pumped_full_model(self.name, machine, self.nominal_derived(scenario, machine),
                                 params.finite(), clips=True)

    def plant_model(self, scenario: "Scenario", machine: Plant) -> PlantModel:
        # sliding mode's k = 0.5 rad/s^2: the disturbance is 0.05 / 41 ~ 1.2e-3 and the
        # linearisation's error ~ 2.6 theta^3 / 6 is smaller still; 0.5 gives a fast
        # reaching phase from theta(0) = pi/30
        params = _nominal(machine.params)  # type: ignore[attr-defined]
        # the view's pole'' with the cart at rest, d the hinge torque -d m l / (M + m)
        view = derived_view(self.nominal_derived(scenario, machine), params.disturbance_torque)
        return PlantModel(scenario.plant.kind, 2, view.accel, affine_in_u=True,
                          x_op=(0.0, 0.0), switching_gain=0.5, compiled=view)

    def linearisation(self, scenario: "Scenario", machine: Plant) -> tuple[np.ndarray, np.ndarray]:
        """The nominal machine's exact ``(A, B)`` at the upright at rest: CasADi's
        derivatives of the derived equations (:meth:`Machine.linearisation`)."""
        return self.nominal_derived(scenario, machine).linearisation()

    def jacobians(self, plant: Plant, at: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """The exact ``(A, B)`` of the ODE twin's equations at ``at`` (CasADi's derivatives)."""
        if isinstance(plant, DerivedCartPoleODE):
            return plant.machine.linearisation(at)
        return None

    def drawing(self, plant: Plant, scenario: "Scenario") -> ModelDrawing:
        """The machine's own geoms (:class:`~tspend.drawing.model.ModelDrawing`),
        on its rail, the cart posed by the extra ``cart_pos``."""
        machine = cartpole_machine(plant)
        slide = machine.joint_names[[j.kind for j in machine.tree.joints].index("slide")]
        return ModelDrawing(machine, self.view_names(plant), "cart-pole", {slide: "cart_pos"})

    def fits_mjcf(self, joint_types: tuple[str, ...]) -> bool:
        # one slide and one hinge: a chain of more is the articulated domain's
        return joint_types.count("slide") == 1 and len(joint_types) == 2

    def check_task(self, plant: Plant, task: "Task", scenario: "Scenario") -> None:
        """The force the reference and the disturbance need against what the actuator can
        give (:func:`tspend.task_feasibility.check_cart_force`)."""
        from tspend.task_feasibility import check_cart_force

        check_cart_force(plant, cartpole_machine(plant), task, scenario)

    def inspect(self, model_path: str, names: dict[str, str] | None = None,
                dt: float | None = None) -> tuple[dict[str, Any], list[str]]:
        """The compiled model's facts (:mod:`tspend.plants.mjcf`), what the ODE of it leaves
        out (``unmodelled``) and the largest force its actuator can apply at rest (None:
        unbounded); the departures from the paper's ideal cart-pole.  ``names``: ``slide``, ``hinge``,
        ``actuator`` (default: the model's only one of each)."""
        from tspend.plants.mujoco_plant import MujocoCartPole, guess_names

        names = names or {}
        slide, hinge, actuator = guess_names(model_path, names.get("slide"), names.get("hinge"),
                                             names.get("actuator"))
        plant = MujocoCartPole(model_path, slide_joint=slide, hinge_joint=hinge,
                               actuator=actuator)
        facts = {"slide_joint": slide, "hinge_joint": hinge, "actuator_name": actuator,
                 **plant.facts.to_json()}
        facts.pop("departures")
        facts["unmodelled"] = plant.unmodelled(dt)
        act = plant.facts.actuator
        force = act.max_force_at_rest() if act is not None else math.inf
        # JSON has no infinity: null is an actuator without any range
        facts["max_force_at_rest"] = force if math.isfinite(force) else None
        return facts, plant.departures(dt)

    def view_names(self, plant: Plant) -> tuple[str, ...]:
        hinge = plant.state_names[1]  # the MJCF's own name of the pole's hinge
        return (hinge, f"{hinge}_dot")

    def chirp_amplitude(self, plant: Plant) -> float:
        """100 N on the paper's 11 kg machine, scaled with the total mass (in units of u:
        divided by the force per unit u); on a limited rail at most the force that swings
        the cart over half its range at the chirp's first 0.1 Hz, so the comparison runs
        longer before the cart meets the rail's end."""
        p: CartPoleParams = plant.params  # type: ignore[attr-defined]
        force = CHIRP_N_PER_KG * (p.M + p.m)
        slide = plant.state_names[0]
        rail = next((j.range for j in plant.joints if j.name == slide and j.range), None)
        if rail is not None:
            half = 0.5 * (rail[1] - rail[0])
            force = min(force, 0.5 * half * (p.M + p.m) * (2.0 * math.pi * CHIRP_F0_HZ) ** 2)
        return force / abs(p.force_per_u)

    def ode_of(self, plant: Plant) -> Plant:
        """The ODE of the MuJoCo ``plant``'s machine: the equations derived from its
        compiled model (:class:`DerivedCartPoleODE`)."""
        return DerivedCartPoleODE(plant, cartpole_machine(plant))  # type: ignore[arg-type]


#: the cart-pole domain
DOMAIN = CartPoleDomain()
