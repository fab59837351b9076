"""What a plant domain is: the one object the rest of tspend asks about a kind of machine.

A *domain* (the cart-pole, the Furuta pendulum, the paper's chain plants) holds everything
its machine means, in its own module under ``tspend/plants/``: the equations, the roles of
its MJCF joints and how each backend is built, its linearisation and the model the
model-based controllers assume (:class:`PlantModel`), the drawing for Rerun
(:class:`~tspend.plants.drawing.base.Drawing`), labels and units (:class:`PlantLabels`), the default task
(:class:`TaskDefaults`) and the scenario configuration class of each plant kind.
:mod:`tspend.plants.registry` maps plant kinds and domain names to domains; the runner,
recorder, cross-check, effects and controllers ask the domain and name no concrete plant.
docs/writing-a-plant.md walks through writing one.
"""

from __future__ import annotations

import math
import re
from abc import ABC, abstractmethod
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, NamedTuple

import numpy as np
from numba.core import types
from numba.extending import overload, register_jitable

from tspend.config import PlantConfig
from tspend.runtime.errors import ScenarioError
from tspend.plants.base import Plant, TaskDefaults  # TaskDefaults: re-exported
from tspend.runtime.jit import JIT
from tspend.runtime.law import jax_form, mark_law, with_jax_form

if TYPE_CHECKING:
    from tspend.config import Scenario
    from tspend.plants.drawing.base import Drawing

__all__ = ["Domain", "Backend", "FullModel", "PlantLabels", "PlantModel", "Quantity",
           "TaskDefaults", "FD_STEP", "VIEW_MODEL", "FULL_STATE", "SYMBOLIC", "PARAMETER_CHANGE",
           "CART_CENTRING", "PUMPED_ENERGY", "CAPABILITIES", "CHIRP_F0_HZ", "CHIRP_F1_HZ",
           "wrap_angle", "COMPILED_VIEW_ACCEL", "central_df_du", "view_accel", "name_slug",
           "unit_slug"]

#: what a domain may provide (:attr:`Domain.provides`), and what a controller kind or an
#: effect may need (:attr:`tspend.controllers.base.Controller.needs`):
#: the model of the task's view (:meth:`Domain.plant_model`; every domain has one)
VIEW_MODEL = "view_model"
#: a full-state model of the machine (:meth:`Domain.full_model`)
FULL_STATE = "full_state"
#: its equations built over CasADi as well (:meth:`FullModel.symbolic`; nonlinear MPC)
SYMBOLIC = "symbolic_model"
#: a change of the machine's parameters during a run (``effects.change``)
PARAMETER_CHANGE = "parameter_change"
#: the cart-centring outer loop on the pole's reference (``effects.outer_loop``)
CART_CENTRING = "cart_centring"
#: one pendulum whose energy a compiled swing-up pumps (:attr:`FullModel.machine`, ``swingup``)
PUMPED_ENERGY = "pumped_energy"
#: each capability, in words (docs/controllers.md's table)
CAPABILITIES = {
    VIEW_MODEL: "a model of the view (f(x, u) of the tracked output's n-th derivative)",
    FULL_STATE: "the full state and a model of the whole machine",
    SYMBOLIC: "the machine's equations over CasADi (exact gradients)",
    PARAMETER_CHANGE: "a change of the machine's parameters during a run",
    CART_CENTRING: "a cart whose position can be centred through the pole's reference",
    PUMPED_ENERGY: "a single pendulum whose energy can be pumped (compiled energy): energy "
                   "pumping does not extend to two or more poles",
}

#: relative step of the central differences of :class:`PlantModel`
FD_STEP = 1e-6

#: the cross-check's open-loop chirp sweeps from CHIRP_F0_HZ to CHIRP_F1_HZ
#: (:meth:`Domain.chirp_amplitude` sizes it)
CHIRP_F0_HZ = 0.1
CHIRP_F1_HZ = 2.0

Accel = Callable[[float, np.ndarray, float, float], float]


def unit_slug(unit: str) -> str:
    """A unit as the end of a column name: ``rad/s`` -> ``rad_s``, ``rad/s²`` -> ``rad_s2``,
    ``N m`` -> ``N_m`` ("" for a dimensionless quantity)."""
    text = unit.replace("²", "2").replace("³", "3").replace("^", "")
    return re.sub(r"[^0-9A-Za-z]+", "_", text).strip("_")


def name_slug(symbol: str) -> str:
    """A symbol as the start of a column name: ``theta'`` -> ``theta_dot``,
    ``x''`` -> ``x_ddot``, ``log10 V`` -> ``log10_V``."""
    text = symbol.replace("'" * 3, "_dddot").replace("'" * 2, "_ddot").replace("'", "_dot")
    return re.sub(r"[^0-9A-Za-z]+", "_", text).strip("_")


class Quantity(NamedTuple):
    """One physical quantity as plotted: short symbol, unit, and what it is; ``column``
    is its name in an exported table before the unit (default: the symbol's)."""

    symbol: str
    unit: str = ""
    meaning: str = ""
    column: str = ""

    def with_unit(self, text: str | None = None) -> str:
        """``"theta (rad)"``, or ``text`` with this quantity's unit."""
        text = self.symbol if text is None else text
        return f"{text} ({self.unit})" if self.unit else text

    def column_name(self, stem: str | None = None) -> str:
        """Its column in an exported table, the unit at the end: ``theta_dot_rad_s``,
        ``cart_x_m``, ``u_N`` (``stem`` in place of the quantity's own)."""
        stem = stem if stem is not None else (self.column or name_slug(self.symbol))
        slug = unit_slug(self.unit)
        return f"{stem}_{slug}" if slug else stem


class PlantLabels(NamedTuple):
    """The task's view x_1 .. x_n, the control and the extras of one domain; the full
    state's quantities in the plants' state order (empty: the full state is the view) and
    the disturbance's."""

    states: tuple[Quantity, ...]
    control: Quantity
    extras: dict[str, Quantity]
    full_state: tuple[Quantity, ...] = ()
    disturbance: Quantity = Quantity("d", "", "disturbance")

    def padded(self, order: int) -> "PlantLabels":
        """These labels for ``order`` states: extra ones are named ``x<i>``."""
        states = tuple(self.states[:order]) + tuple(Quantity(f"x{i + 1}")
                                                    for i in range(len(self.states), order))
        return self._replace(states=states)

    def extra(self, name: str) -> Quantity:
        return self.extras.get(name, Quantity(name))

    def of_state(self, names: tuple[str, ...], units: tuple[str, ...],
                 view: tuple[str, ...]) -> tuple[Quantity, ...]:
        """The quantity of each entry of a plant's full state ``names`` (with ``units``),
        whose task views ``view``: the domain's :attr:`full_state` when it names them all,
        else the view's labels for the view's entries and the plant's names for the rest."""
        if len(self.full_state) == len(names):
            return self.full_state
        padded = self.padded(len(view)).states
        out = []
        for name, unit in zip(names, units):
            if name in view:
                q = padded[view.index(name)]
                out.append(q._replace(unit=q.unit or unit))
            else:
                out.append(Quantity(name, unit, column=name_slug(name)))
        return tuple(out)


#: the type of a domain's compiled view model (:attr:`PlantModel.compiled`, a module-level
#: NamedTuple) -> its ``f(model, t, x, u, d)`` for compiled code
COMPILED_VIEW_ACCEL: dict[type, Callable] = {}


def _view_accel_jax(model: Any, t: Any, x: Any, u: Any, d: Any) -> Any:
    """:func:`view_accel`'s JAX form: the JAX form of the law the model's domain registered."""
    return jax_form(COMPILED_VIEW_ACCEL[type(model)])(model, t, x, u, d)


@with_jax_form(_view_accel_jax)
def view_accel(model: Any, t: float, x: np.ndarray, u: float, d: float) -> float:
    """``x_n' = f(t, x, u, d)`` of a view model: from Python its ``accel`` (a
    :class:`PlantModel` or a compiled view model); in compiled code, and in a law's JAX
    form (:mod:`tspend.runtime.law`), the law its domain registered in
    :data:`COMPILED_VIEW_ACCEL` for the model's type."""
    return model.accel(t, x, u, d)


@overload(view_accel, jit_options=JIT)
def _view_accel(model, t, x, u, d):
    cls = model.instance_class if isinstance(model, types.BaseNamedTuple) else None
    accel = COMPILED_VIEW_ACCEL.get(cls)
    if accel is None:
        return None

    def impl(model, t, x, u, d):
        return accel(model, t, x, u, d)

    return impl


@mark_law
@register_jitable
def central_df_du(model: Any, t: float, x: np.ndarray, u: float) -> float:
    """``df/du`` by central differences of step ``FD_STEP (1 + |u|)`` (``d = 0``); the one
    implementation, for :class:`PlantModel` and for compiled controllers."""
    h = FD_STEP * (1.0 + abs(u))
    return (view_accel(model, t, x, u + h, 0.0) - view_accel(model, t, x, u - h, 0.0)) / (2.0 * h)


@dataclass(frozen=True)
class PlantModel:
    """The true ``f(t, x, u)`` of a plant's view (``d_d = 0``), its operating point, and
    whether ``f`` is affine in ``u`` (then ``f = f(t, x, 0) + u (f(t, x, 1) - f(t, x, 0))``
    exactly).  Derivatives are central differences of step ``FD_STEP (1 + |v|)``: their
    truncation error is ~1e-12 relative on the plants here.  ``switching_gain`` is the
    domain's margin over the model error on its operating region (sliding mode's ``k``).
    """

    name: str
    order: int
    accel: Accel
    affine_in_u: bool
    x_op: tuple[float, ...]
    u_op: float = 0.0
    switching_gain: float = 1.0
    #: the same ``f`` for compiled code: an instance of a NamedTuple type registered in
    #: :data:`COMPILED_VIEW_ACCEL`, whose ``accel`` method is ``accel`` here (None: the
    #: domain offers none, the model-based kinds that need ``f`` run in Python)
    compiled: Any = None

    def f(self, t: float, x: np.ndarray, u: float) -> float:
        return self.accel(t, x, u, 0.0)

    def df_du(self, t: float, x: np.ndarray, u: float) -> float:
        return central_df_du(self, t, x, u)

    def linearisation(self) -> tuple[np.ndarray, float]:
        """``(a, b)``: ``df/dx`` (n,) and ``df/du`` at ``(t = 0, x*, u*)``."""
        x0 = np.asarray(self.x_op, dtype=float)
        a = np.empty(self.order)
        for i in range(self.order):
            h = FD_STEP * (1.0 + abs(x0[i]))
            xp, xm = x0.copy(), x0.copy()
            xp[i] += h
            xm[i] -= h
            a[i] = (self.accel(0.0, xp, self.u_op, 0.0) - self.accel(0.0, xm, self.u_op, 0.0)) / (2 * h)
        return a, self.df_du(0.0, x0, self.u_op)

    def state_space(self) -> tuple[np.ndarray, np.ndarray]:
        """``(A, B)`` of the linearised chain of integrators: ``A`` has ones above the
        diagonal and last row ``a``; ``B = b e_n``."""
        a, b = self.linearisation()
        n = self.order
        A = np.eye(n, k=1)
        A[-1, :] = a
        B = np.zeros((n, 1))
        B[-1, 0] = b
        return A, B


@mark_law
@register_jitable
def wrap_angle(a: float) -> float:
    """``a`` wrapped to (-pi, pi]: the error of an angle that may have turned over."""
    return a - 2.0 * math.pi * math.ceil((a - math.pi) / (2.0 * math.pi))


@dataclass(frozen=True)
class FullModel:
    """What the full-state controller kinds (full LQR, ``mpc``, ``swingup``) know of a
    machine: an underactuated mechanism with positions ``q`` and velocities ``q'`` (the
    full state ``s = [q, q']``, named as the plant names it), one input ``u`` and
    ``q'' = accel(s, u)`` from the domain's own equations (written once, in the domain's
    physics module; a domain builds this in :meth:`Domain.full_model`).

    ``accel_factory(sin, cos, tanh)`` returns ``accel(s, u) -> q''`` (a tuple of length
    ``len(q)``) over those math functions: ``math``'s give numbers, CasADi's symbols (the
    MPC's model is the simulated one, not a copy).  ``energy(s)`` is the pendulum's energy
    about its pivot, 0 upright at rest (the domain's formula); ``angles`` marks the states
    that wrap; ``pole`` is the pendulum angle's index (upright 0, hanging pi),
    ``actuated`` the driven coordinate's (cart, arm); ``q_lo``/``q_hi`` bound the
    positions (+/-inf: free; the rail, a joint's range, a task's state bound) and
    ``u_lo``/``u_hi`` the input (the actuator's range), filled in by
    :func:`tspend.controllers.full_model.full_model`.

    Derived here, each documented as such: the linearisation by central differences
    (step ``FD_STEP (1 + |v|)``) and the input's affine map ``q'' = q''(s, 0) + u dq''/du``
    (the domains' inputs are forces or voltages entering linearly).
    """

    domain: str
    state_names: tuple[str, ...]
    accel_factory: Callable[..., Callable[[Any, Any], tuple]]
    energy: Callable[[np.ndarray], float]
    pole: int
    actuated: int
    angles: tuple[bool, ...]
    u_lo: float = -math.inf
    u_hi: float = math.inf
    q_lo: tuple[float, ...] = ()
    q_hi: tuple[float, ...] = ()
    parameters: dict = field(default_factory=dict)
    #: the derived machine as compiled code takes it
    #: (:class:`~tspend.plants.articulated.domain.DerivedFull`) behind ``accel_factory`` and
    #: ``energy``; None where the swing-up does not pump the machine
    machine: Any = None
    #: the unit of the actuated coordinate's acceleration ("m/s^2", "rad/s^2")
    accel_unit: str = ""
    #: every joint that must stay upright (() = just ``pole``): a chain of links
    poles: tuple[int, ...] = ()

    @property
    def upright(self) -> tuple[int, ...]:
        """The indices of every pole (``poles``, else ``pole``)."""
        return self.poles or (self.pole,)

    @property
    def size(self) -> int:
        return len(self.state_names)

    @property
    def dof(self) -> int:
        return self.size // 2

    @cached_property
    def numeric(self) -> Callable[[np.ndarray, float], tuple]:
        """``q''(s, u)`` over ``math`` (numbers)."""
        return self.accel_factory(math.sin, math.cos, math.tanh)

    def rhs(self, s: np.ndarray, u: float) -> np.ndarray:
        """``s' = [q', q''(s, u)]``."""
        qdd = self.numeric(np.asarray(s, dtype=float), u)
        return np.concatenate([np.asarray(s[self.dof:], dtype=float), np.asarray(qdd, dtype=float)])

    def symbolic(self) -> Callable[[Any, Any], Any]:
        """``s' = f(s, u)`` as CasADi expressions of an ``SX``/``MX`` state and input."""
        import casadi

        accel = self.accel_factory(casadi.sin, casadi.cos, casadi.tanh)

        def f(s, u):
            return casadi.vertcat(s[self.dof:], *accel(s, u))

        return f

    def rk4_map(self, dt: float, substeps: int = 1, name: str = "rk4") -> Any:
        """``s_next = G(s, u)``: ``substeps`` classical RK4 steps of ``dt / substeps`` over
        :meth:`symbolic` with u held (the shooting map of MPC and planning), a CasADi
        Function named ``name``."""
        import casadi

        f = self.symbolic()
        s, u = casadi.SX.sym("s", self.size), casadi.SX.sym("u")
        sk, dh = s, dt / substeps
        for _ in range(substeps):
            k1 = f(sk, u)
            k2 = f(sk + dh / 2 * k1, u)
            k3 = f(sk + dh / 2 * k2, u)
            k4 = f(sk + dh * k3, u)
            sk = sk + dh / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        return casadi.Function(name, [s, u], [sk])

    def linearisation(self, s_op: np.ndarray | None = None,
                      u_op: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
        """``(A, B)`` at ``(s*, u*)`` (default the upright at rest) by central differences."""
        s0 = np.zeros(self.size) if s_op is None else np.asarray(s_op, dtype=float)
        N = self.size
        A = np.empty((N, N))
        for i in range(N):
            h = FD_STEP * (1.0 + abs(s0[i]))
            sp, sm = s0.copy(), s0.copy()
            sp[i] += h
            sm[i] -= h
            A[:, i] = (self.rhs(sp, u_op) - self.rhs(sm, u_op)) / (2.0 * h)
        h = FD_STEP * (1.0 + abs(u_op))
        B = ((self.rhs(s0, u_op + h) - self.rhs(s0, u_op - h)) / (2.0 * h))[:, None]
        return A, B

    def input_map(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(q''(s, 0), dq''/du)``: the accelerations are affine in ``u``."""
        f = self.numeric
        s = np.asarray(s, dtype=float)
        a0 = np.asarray(f(s, 0.0), dtype=float)
        return a0, np.asarray(f(s, 1.0), dtype=float) - a0

    def error(self, s: np.ndarray, s_ref: np.ndarray) -> np.ndarray:
        """``s - s_ref`` with the angles' errors wrapped to (-pi, pi]."""
        e = np.asarray(s, dtype=float) - s_ref
        for i, wraps in enumerate(self.angles):
            if wraps:
                e[i] = wrap_angle(e[i])
        return e


@dataclass(frozen=True)
class Backend:
    """One plant kind of a domain: its configuration class and its builder."""

    config: type[PlantConfig]
    build: Callable[[PlantConfig, Path], Plant]
    #: True when the kind steps an MJCF (its config names the model file)
    mujoco: bool = False


class Domain(ABC):
    """One kind of machine, on every backend it has (module docstring)."""

    #: the domain's name ("cartpole", "furuta", "duffing", ...)
    name: str = ""
    #: plant kind -> its backend
    kinds: dict[str, Backend] = {}
    #: labels and units of the view, the control and the extras
    labels: PlantLabels = PlantLabels((), Quantity("u"), {})
    #: the default task
    task: TaskDefaults = TaskDefaults(view=())
    #: the MJCF a MuJoCo backend steps when the configuration names none ("" = none)
    default_model: str = ""
    #: the state whose range is a rail (effects.rail acts on it), "" = none
    rail_joint: str = ""
    #: what the domain provides (:data:`FULL_STATE`, :data:`SYMBOLIC`,
    #: :data:`PARAMETER_CHANGE`, :data:`CART_CENTRING`): what a controller kind's
    #: ``needs`` and the effects are checked against before anything is built
    provides: frozenset[str] = frozenset({VIEW_MODEL})
    #: True when the equations are derived from the model (the cross-check then compares
    #: them with MuJoCo's mj_forward at random states: tspend.studies.crosscheck_derived)
    derives_equations: bool = False

    @property
    def order(self) -> int:
        """The length n of the task's view: what the paper's controllers see."""
        return len(self.task.view)

    def model_file(self, cfg: PlantConfig) -> str:
        """The MJCF a configuration names (the domain's default for an ODE's)."""
        return self.default_model

    def model_path(self, scenario: "Scenario") -> Path:
        """The scenario's MJCF (:func:`tspend.shipped.locate`; as written when not found,
        so the loader's message names it)."""
        from tspend.shipped import locate

        p = self.model_file(scenario.plant)
        return locate(p, scenario.path) or Path(p)

    def build(self, scenario: "Scenario", kind: str | None = None) -> Plant:
        """The scenario's plant, or the same machine on backend ``kind`` of this domain,
        not yet reset."""
        kind = kind or scenario.plant.kind
        if kind not in self.kinds:
            raise ScenarioError(f"plant kind {kind!r} is not a backend of domain {self.name!r} "
                             f"(its kinds: {', '.join(self.kinds)})")
        return self.kinds[kind].build(scenario.plant, self.model_path(scenario))

    def nominal_values(self, scenario: "Scenario") -> dict[str, float]:
        """The values the scenario's machine takes for the numeric ``[plant]`` keys it
        leaves at 0 and fills in itself (a MuJoCo model's own masses, say): the nominal
        of a relative ``[randomize]`` draw (:mod:`tspend.plants.randomize`).  A key not
        listed is 0 on the machine.  By default none: a 0 is 0."""
        return {}

    # The three models a model-based controller designs on take ``machine``: the nominal
    # machine the runner built once (tspend.loop.simulation.nominal_machine, a plant of
    # this domain built from the scenario as written); none of them builds a plant.

    @abstractmethod
    def plant_model(self, scenario: "Scenario", machine: Plant) -> PlantModel:
        """The model the model-based controllers assume for the scenario's plant."""

    def full_model(self, scenario: "Scenario", machine: Plant) -> FullModel | None:
        """The machine's full-state model, its bounds left free (None: the domain has only
        its view).  A domain returning one lists :data:`FULL_STATE` in :attr:`provides`."""
        return None

    def linearisation(self, scenario: "Scenario",
                      machine: Plant) -> tuple[np.ndarray, np.ndarray] | None:
        """``(A, B)`` of the FULL state (``plant.state_names`` order) of the model the
        model-based controllers assume (``lqr``'s full design) about the domain's
        equilibrium, or None when the domain has none beyond the view's."""
        return None

    def jacobians(self, plant: Plant, at: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
        """The exact ``(A, B)`` of the analytic ``plant``'s equations at the full state
        ``at`` (``plant.state_names`` order), ``u = 0``; None when the domain has no
        closed form there (:func:`tspend.plants.linearize.linearize` then takes central
        differences of the plant's own right-hand side)."""
        return None

    def drawing(self, plant: Plant, scenario: "Scenario") -> "Drawing | None":
        """What the recorder draws of ``plant`` in 3D (None: nothing)."""
        return None

    def mujoco_kind(self) -> str | None:
        """The domain's MuJoCo plant kind (the cross-check's first backend), or None."""
        return next((k for k, b in self.kinds.items() if b.mujoco), None)

    def ode_kind(self) -> str | None:
        """The domain's analytic plant kind (the cross-check's second backend), or None."""
        return next((k for k, b in self.kinds.items() if not b.mujoco), None)

    def fits_mjcf(self, joint_types: tuple[str, ...]) -> bool:
        """Whether an MJCF with these joint types ("slide", "hinge", ...) looks like this
        domain's machine (``tspend inspect`` picks the domain by it)."""
        return False

    def fits_model(self, model: Any) -> bool:
        """Whether the compiled ``mujoco.MjModel`` is this domain's machine (``tspend
        inspect``); by default by its joint types alone (:meth:`fits_mjcf`)."""
        import mujoco

        names = {int(mujoco.mjtJoint.mjJNT_SLIDE): "slide", int(mujoco.mjtJoint.mjJNT_HINGE): "hinge",
                 int(mujoco.mjtJoint.mjJNT_BALL): "ball", int(mujoco.mjtJoint.mjJNT_FREE): "free"}
        return self.fits_mjcf(tuple(names[int(t)] for t in model.jnt_type))

    def inspect(self, model_path: str, names: dict[str, str] | None = None,
                dt: float | None = None) -> tuple[dict[str, Any], list[str]]:
        """``(facts, departures)`` of an MJCF as this domain reads it (``tspend inspect``;
        ``names``: the joints and actuator by role, e.g. ``{"slide": "cart_x"}``; ``dt``:
        the sample time to check the timestep against)."""
        raise NotImplementedError(f"domain {self.name!r} does not read MJCF files")

    def view_names(self, plant: Plant) -> tuple[str, ...]:
        """The full-state names of ``plant``'s view (the task's, under the plant's own
        joint names)."""
        return self.task.view

    def chirp_amplitude(self, plant: Plant) -> float:
        """The amplitude of the cross-check's open-loop chirp input on ``plant``: large
        enough to swing the machine through its whole range, in units of u."""
        return 1.0

    def ode_of(self, plant: Plant) -> Plant:
        """The analytic plant of the very machine the MuJoCo ``plant`` compiled."""
        raise NotImplementedError(f"domain {self.name!r} has no analytic twin of its MuJoCo plant")

