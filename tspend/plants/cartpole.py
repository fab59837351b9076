"""The cart-pole domain: an articulated machine (docs/articulated.md) with the paper's names.

A cart-pole is its MJCF (``models/cartpole.xml`` by default) read and derived like every
other machine (:class:`~tspend.plants.articulated.machine.Machine`): one MuJoCo plant
(:class:`MujocoCartPole`, the articulated one), one derived model (nominal for the
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
geoms (:class:`~tspend.plants.drawing.model.ModelDrawing`, with its rail).
"""

from __future__ import annotations

import copy
import math
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable

import mujoco
import numpy as np

from tspend.config import PlantConfig
from tspend.plants.drawing.model import ModelDrawing
from tspend.runtime.errors import ScenarioError
from tspend.plants import mjcf
from tspend.plants.articulated.domain import (ArticulatedMujoco, ArticulatedODE, derived_view,
    pumped_full_model)
from tspend.plants.articulated.machine import Machine
from tspend.plants.articulated.derive import parameter_table
from tspend.plants.articulated.tree import read_tree
from tspend.plants.base import CartPolePlant, InputInfo, MachinePlant, Plant, TaskDefaults, read_as
from tspend.plants.mjcf import AXIAL_INERTIA_RATIO, OVERRIDABLE, CartPoleParams, compile_cartpole
from tspend.plants.domain import (CART_CENTRING, CHIRP_F0_HZ, FULL_STATE,
    PARAMETER_CHANGE, PUMPED_ENERGY, SYMBOLIC, VIEW_MODEL, Backend, Domain,
    FullModel, PlantLabels, PlantModel, Quantity)

if TYPE_CHECKING:
    from tspend.config import Scenario

__all__ = ["CartPoleParams", "CartPoleConfig", "MujocoCartPoleConfig", "MujocoCartPole",
           "DerivedCartPoleODE",
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
    return read_as(plant, MachinePlant).machine


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


class _CartPole:
    """What both cart-pole plants say alike, over the articulated machine's: what the MuJoCo
    plant ``_mujoco`` read off the compiled model (itself; the ODE twin's source) and the
    cart as the extras ``cart_pos``, ``cart_vel`` (the machine's two joints: the pole its
    view, the slide the other)."""

    machine: Machine
    _mujoco: "MujocoCartPole"
    domain = "cartpole"
    full_state: Callable[[], np.ndarray]  # the plant's (the other base class defines it)

    #: the motor on the slide joint, bounded by its ctrlrange when ``ctrllimited``
    inputs = property(lambda self: self._mujoco._inputs)
    #: the ODE of the compiled model (:meth:`ModelFacts.params`): the metrics' numbers
    params = property(lambda self: self._mujoco._params)
    #: sign of d(theta'')/du at the upright, measured by MuJoCo on the compiled model
    gain_sign = property(lambda self: self._mujoco.facts.gain_sign)

    def parameters(self) -> dict[str, float]:
        return self.params.finite()

    def extras(self) -> dict[str, float]:
        s, cart = self.full_state(), 1 - self.machine.view_joint
        return {"cart_pos": float(s[cart]), "cart_vel": float(s[2 + cart])}

    def extras_index(self) -> np.ndarray:
        """The cart's position and velocity in the full state [qpos; qvel]."""
        cart = 1 - self.machine.view_joint
        return np.array([cart, 2 + cart], dtype=np.intp)


class MujocoCartPole(_CartPole, ArticulatedMujoco):
    """Example 3's cart-pole as a MuJoCo model (``models/cartpole.xml`` reproduces the
    paper's Example 3, docs/paper-notes.md section 7): the articulated MuJoCo plant of its
    compiled model, the hinge its pole, with the ``[plant]`` numbers written into the
    model (:func:`~tspend.plants.mjcf.compile_cartpole`) and read back from the compiled
    one (:attr:`params`), ``d`` the hinge torque ``-d m l / (M + m)``.

    Parameters
    ----------
    model_path:
        MJCF file, e.g. ``models/cartpole.xml``.
    slide_joint, hinge_joint, actuator:
        names of the cart's slide joint, the pole's hinge and the motor on the slider.
    overrides:
        what to write into the model before compiling (verified on the compiled model):
        a dict of some of M, m, l, J, g (the rest stay the model's own), or a
        :class:`CartPoleParams` for all of them.  The pole's COM moves to ``l`` from the
        pivot along the pole, its inertia becomes J (the uniform rod's 4/3 m l^2 unless
        given) and the pole's visual geoms stretch with it.  None: the model as it is.
    integrator:
        ``"RK4"`` (the model's default, matches the ODE), ``"Euler"``, ``"implicit"`` or
        ``"implicitfast"``; only for the cross-check's contrast figures.
    timestep:
        overrides the model's physics timestep.
    gear:
        if given, the actuator's gain (cart force per unit of u) written into the model
        and read back from the compiled one.
    ctrl_unbounded:
        True leaves u unbounded (the actuator's ``ctrlrange`` off): the paper's machine.

    Raises
    ------
    ScenarioError
        missing or unparsable model file, missing or mistyped joint or actuator, an
        actuator that does not drive the slide joint, an unknown integrator, or a model
        whose equations cannot be derived (one line naming what to change).
    """

    name: str = "cartpole_mujoco"
    _mujoco = property(lambda self: self)

    def __init__(self, model_path: str | Path, slide_joint: str = "slider",
                 hinge_joint: str = "hinge", actuator: str = "force",
                 overrides: CartPoleParams | dict[str, float] | None = None,
                 integrator: str | None = None, timestep: float | None = None,
                 cart_damping: float | None = None, hinge_damping: float | None = None,
                 cart_friction: float | None = None, hinge_friction: float | None = None,
                 gear: float | None = None, ctrl_unbounded: bool = False) -> None:
        model, self.facts, written = compile_cartpole(
            model_path, slide_joint, hinge_joint, actuator, overrides, integrator, timestep,
            cart_damping, hinge_damping, cart_friction, hinge_friction, gear, ctrl_unbounded)
        #: what the scenario wrote into the model (name -> value); empty: the model's own
        self.overridden: dict[str, float] = written
        self.slide_joint, self.hinge_joint, self.actuator = slide_joint, hinge_joint, actuator
        self._params = self.facts.params()
        # a cart-pole is an articulated machine: its equations (the controllers' models, the
        # ODE twin, the task check) are derived from the model, so a model that cannot be
        # derived is refused here, in one line naming what to change, not midway
        machine = Machine(model, str(Path(model_path)), actuator, (hinge_joint,))
        # d_d enters theta'' like a hinge torque tau = -d_d m l / (M + m) (CartPoleParams)
        ArticulatedMujoco.__init__(self, machine, d_scale=self._params.disturbance_torque)
        a = self._act
        lo, hi = (float(v) for v in model.actuator_ctrlrange[a]) \
            if model.actuator_ctrllimited[a] else (-math.inf, math.inf)
        # u is what the actuator takes: a force for a motor, a speed or a position for a
        # velocity or position servo
        unit = {"velocity": "m/s", "position": "m"}.get(self.facts.actuator_type, "N")
        per_unit = self.facts.gear * self.facts.gain
        if unit == "N" and per_unit != 1.0 and "gear" not in self.overridden:
            # the model's own gear or gain other than 1: u is its control, the force beside
            # it (a gear the scenario sets or draws is plant.gear: u stays the ODE's force)
            self._inputs = (InputInfo(actuator, "ctrl", lo, hi, "N", per_unit),)
        else:
            self._inputs = (InputInfo(actuator, unit, lo, hi),)

    def unmodelled(self, dt: float | None = None) -> list[str]:
        """What the ODE of this model (:attr:`params`) does not reproduce."""
        return mjcf.unmodelled(self.facts, dt)

    def departures(self, dt: float | None = None) -> list[str]:
        """How this model departs from the paper's ODE (with ``dt``: and the sample time)."""
        # a gear the scenario set (or [randomize] drew) is recorded as plant.gear
        return mjcf.departures(self.facts, dt, gear_chosen="gear" in self.overridden)

    def set_params(self, p: CartPoleParams) -> None:
        """Change M, m, l (J) of the running machine, as a payload picked up would.

        Writes the compiled model's inertials in place, exactly as an override would
        have compiled them, and the derived machine's parameters (its ODE twin's too)
        read from it again; the state is kept.
        """
        m = self.model
        hinge = m.joint(self.hinge_joint).id
        pole, cart = int(m.jnt_bodyid[hinge]), int(m.jnt_bodyid[m.joint(self.slide_joint).id])
        pivot = m.jnt_pos[hinge]
        arm = m.body_ipos[pole] - pivot
        axis = arm / np.linalg.norm(arm)
        i_perp = p.pole_inertia_pivot - p.m * p.l ** 2
        if i_perp <= 0.0 or p.M <= 0.0 or p.m <= 0.0 or p.l <= 0.0:
            raise ScenarioError(f"{self.model_path}: cannot change to M={p.M:g}, m={p.m:g}, "
                                f"l={p.l:g}, J={p.pole_inertia_pivot:g}")
        m.body_mass[pole] = p.m
        m.body_ipos[pole] = pivot + p.l * axis
        quat = m.body_iquat[pole].copy()
        mujoco.mju_quatZ2Vec(quat, axis)
        m.body_iquat[pole] = quat
        m.body_inertia[pole] = (i_perp, i_perp, i_perp * AXIAL_INERTIA_RATIO)
        carried = float(m.body_subtreemass[cart]) - float(m.body_mass[cart]) - self._params.m
        m.body_mass[cart] = p.M - carried
        m.body_subtreemass[cart] = p.M + p.m
        m.body_subtreemass[pole] = p.m
        self._params = replace(self._params, M=p.M, m=p.m, l=p.l, J=p.J)
        self._d_to_tau = self._params.disturbance_torque
        self.machine.p[:] = parameter_table(read_tree(m))[1]

    def _place(self, x0: np.ndarray) -> None:
        """Pole at ``x0 = [theta, theta']``, cart at rest where the model puts it."""
        if x0.shape != (self.order,):
            raise ValueError(f"{self.name}: initial state must have {self.order} entries, "
                             f"got {x0.shape}")
        self._qpos[self._d_dof] = x0[0]
        self._qvel[self._d_dof] = x0[1]


class DerivedCartPoleODE(_CartPole, ArticulatedODE):
    """The ODE twin of a MuJoCo cart-pole: the equations derived from its compiled model
    (its machine, :class:`~tspend.plants.articulated.domain.ArticulatedODE`), ``d``
    applied as MuJoCo's cart-pole applies it, the hinge torque ``-d m l / (M + m)``, and
    MuJoCo's soft dry friction (``frictionloss``) as the smooth ``F tanh(v / v_s)`` the
    hand-written ODE has (:func:`~tspend.plants.articulated.domain.applied_forces`; they
    agree in kind, a departure the cross-check names).  Its inputs, gain sign and
    ``params`` are the MuJoCo plant's, so both backends describe one machine."""

    def __init__(self, source: MujocoCartPole) -> None:
        ArticulatedODE.__init__(self, source.machine)
        self.name, self.domain = "cartpole_ode", "cartpole"
        self._mujoco = source
        self._d_scale = self.params.disturbance_torque
        # MuJoCo's frictionloss as the hand-written ODE has it, F tanh(v / v_s)
        self._dry[1 - self.machine.view_joint] = self.params.cart_friction
        self._dry[self.machine.view_joint] = self.params.hinge_friction

    def set_params(self, params: CartPoleParams) -> None:
        """Change M, m, l (J) while it runs (a payload picked up): written into the
        compiled model, and so into the machine both share, by the MuJoCo plant; the
        state is kept."""
        self._mujoco.set_params(params)
        self._d_scale = self.params.disturbance_torque


def _nominal(params: CartPoleParams) -> CartPoleParams:
    """The rigid machine of ``params``: a nominal model leaves a rig's friction out."""
    return replace(params, cart_damping=0.0, hinge_damping=0.0, cart_friction=0.0,
                   hinge_friction=0.0)


def _build_mujoco(cfg: PlantConfig, model_path: Path) -> Plant:
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
    return MujocoCartPole(model_path, slide_joint=mj.slide_joint, hinge_joint=mj.hinge_joint,
                          actuator=mj.actuator, overrides=overrides,
                          integrator=mj.integrator or None, timestep=mj.timestep or None,
                          gear=mj.gear or None, ctrl_unbounded=unbounded, **friction)


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
        if isinstance(plant, MujocoCartPole):
            f = plant.facts
            return {"M": f.cart_mass, "m": f.pole_mass, "l": f.pole_com,
                    "J": f.pole_inertia_pivot, "g": f.gravity, "gear": f.force_per_u,
                    "cart_damping": f.slide.damping, "hinge_damping": f.hinge.damping,
                    "cart_friction": f.slide.frictionloss,
                    "hinge_friction": f.hinge.frictionloss}
        p = read_as(plant, CartPolePlant).params
        return {"J": p.pole_inertia_pivot, "gear": p.force_per_u}

    def nominal_derived(self, scenario: "Scenario", plant: Plant) -> Machine:
        """The derived machine the controllers assume (:func:`nominal_machine` of
        :func:`cartpole_machine` of the nominal ``plant``)."""
        return nominal_machine(cartpole_machine(plant))

    def full_model(self, scenario: "Scenario", machine: Plant) -> FullModel:
        """The nominal machine over ``[slider, hinge, slider_dot, hinge_dot]`` (the plant's
        own joint names), with MuJoCo's clips of ctrl and force (:func:`pumped_full_model`)."""
        params = _nominal(read_as(machine, CartPolePlant).params)
        return pumped_full_model(self.name, machine, self.nominal_derived(scenario, machine),
                                 params.finite(), clips=True)

    def plant_model(self, scenario: "Scenario", machine: Plant) -> PlantModel:
        # sliding mode's k = 0.5 rad/s^2: the disturbance is 0.05 / 41 ~ 1.2e-3 and the
        # linearisation's error ~ 2.6 theta^3 / 6 is smaller still; 0.5 gives a fast
        # reaching phase from theta(0) = pi/30
        params = _nominal(read_as(machine, CartPolePlant).params)
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
        """The machine's own geoms (:class:`~tspend.plants.drawing.model.ModelDrawing`),
        on its rail, the cart posed by the extra ``cart_pos``."""
        machine = cartpole_machine(plant)
        slide = machine.joint_names[[j.kind for j in machine.tree.joints].index("slide")]
        return ModelDrawing(machine, self.view_names(plant), "cart-pole", {slide: "cart_pos"})

    def fits_mjcf(self, joint_types: tuple[str, ...]) -> bool:
        # one slide and one hinge: a chain of more is the articulated domain's
        return joint_types.count("slide") == 1 and len(joint_types) == 2

    def inspect(self, model_path: str, names: dict[str, str] | None = None,
                dt: float | None = None) -> tuple[dict[str, Any], list[str]]:
        """The compiled model's facts (:mod:`tspend.plants.mjcf`), what the ODE of it leaves
        out (``unmodelled``) and the largest force its actuator can apply at rest (None:
        unbounded); the departures from the paper's ideal cart-pole.  ``names``: ``slide``, ``hinge``,
        ``actuator`` (default: the model's only one of each)."""
        from tspend.plants.mujoco_plant import guess_names

        names = names or {}
        slide, hinge, actuator = guess_names(model_path, names.get("slide"), names.get("hinge"),
                                             names.get("actuator"))
        # the compiled model read, not derived: inspect shows what a model the derivation
        # refuses holds, and why
        f = compile_cartpole(model_path, slide, hinge, actuator)[1]
        facts = {"slide_joint": slide, "hinge_joint": hinge, "actuator_name": actuator,
                 **f.to_json()}
        facts.pop("departures")
        facts["unmodelled"] = mjcf.unmodelled(f, dt)
        force = f.actuator.max_force_at_rest() if f.actuator is not None else math.inf
        # JSON has no infinity: null is an actuator without any range
        facts["max_force_at_rest"] = force if math.isfinite(force) else None
        return facts, mjcf.departures(f, dt)

    def view_names(self, plant: Plant) -> tuple[str, ...]:
        hinge = plant.state_names[1]  # the MJCF's own name of the pole's hinge
        return (hinge, f"{hinge}_dot")

    def chirp_amplitude(self, plant: Plant) -> float:
        """100 N on the paper's 11 kg machine, scaled with the total mass (in units of u:
        divided by the force per unit u); on a limited rail at most the force that swings
        the cart over half its range at the chirp's first 0.1 Hz, so the comparison runs
        longer before the cart meets the rail's end."""
        p = read_as(plant, CartPolePlant).params
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
        return DerivedCartPoleODE(read_as(plant, MujocoCartPole))


#: the cart-pole domain
DOMAIN = CartPoleDomain()
