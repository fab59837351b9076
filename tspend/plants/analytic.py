"""Analytic plants of section 4 of the paper, integrated with RK4 under zero-order hold.

Every plant is a chain of integrators (6): ``x_i' = x_{i+1}`` for i < n and
``x_n' = accel(t, x, u, d)``.  ``u`` and the disturbance ``d`` are held over each
controller sample, as a digital controller would hold them; time-varying terms of the
plant itself (Duffing's forcing) are evaluated at each RK4 stage.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, Callable, NamedTuple

import numpy as np
from numba.core import types
from numba.extending import overload, register_jitable

from tspend.config import AnalyticPlantConfig
from tspend.plants.base import Plant, TaskDefaults
from tspend.plants.domain import (COMPILED_VIEW_ACCEL, Backend, Domain, PlantLabels, PlantModel,
                                  Quantity)
from tspend.runtime.jit import JIT

if TYPE_CHECKING:
    from tspend.config import Scenario

Accel = Callable[[float, np.ndarray, float, float], float]


@register_jitable
def nonaffine_accel(t: float, x: np.ndarray, u: float, d: float) -> float:
    """Example 1: ``x2' = 0.2 (1 + e^{x1 x2}) (2 + sin x2) (u + e^u - 1) + d_d``."""
    x1, x2 = x[0], x[1]
    return 0.2 * (1.0 + math.exp(x1 * x2)) * (2.0 + math.sin(x2)) * (u + math.exp(u) - 1.0) + d


@register_jitable
def duffing_accel(t: float, x: np.ndarray, u: float, d: float) -> float:
    """Example 2: ``x2' = -0.1 x2 - x1^3 + 12 cos t + u + d_d``."""
    x1, x2 = x[0], x[1]
    # x1 ** 3.0, not x1**3: numba expands an integer power into products, whose rounding
    # differs from pow(); a float exponent is pow() in Python and in compiled code alike
    return -0.1 * x2 - x1 ** 3.0 + 12.0 * math.cos(t) + u + d


#: Example 3's cart-pole: cart and pole masses (kg), the pole's half length (m), gravity
EX3_M_KG, EX3_M_POLE_KG, EX3_L_M, EX3_G = 10.0, 1.0, 3.0, 9.8


@register_jitable
def cartpole_accel(t: float, x: np.ndarray, u: float, d: float) -> float:
    """Example 3, the cart-pole, as the paper writes it (x1 the pole's angle from upright,
    u the force on the cart, M = 10 kg, m = 1 kg, l = 3 m the pole's half length, g = 9.8):
    ``x2' = (m l x2^2 sin x1 cos x1 - (M + m) g sin x1 - u cos x1 + d_d)
    / (m l cos^2 x1 - 4/3 l (M + m))``.

    The uniform rod's equation of the pole with the cart free; the plants of the
    ``cartpole`` domain carry the cart as well, and their view's equation is this one on
    the paper's machine (tests/test_cartpole_derived.py)."""
    M, m, l, g = EX3_M_KG, EX3_M_POLE_KG, EX3_L_M, EX3_G
    s, c = math.sin(x[0]), math.cos(x[0])
    return ((m * l * x[1] * x[1] * s * c - (M + m) * g * s - u * c + d)
            / (m * l * c * c - 4.0 / 3.0 * l * (M + m)))


@register_jitable
def third_order_accel(t: float, x: np.ndarray, u: float, d: float) -> float:
    """A nonaffine third-order plant (not in the paper) to exercise n = 3.

    ``x3' = -x1 - 2 x2 - 1.5 x3 + 0.5 sin(x1) x2 + (1.5 + cos x1) (u + 0.2 tanh u) + d_d``;
    ``df/du = (1.5 + cos x1)(1 + 0.2 sech^2 u) >= 0.5``, so Assumption 5 holds with a
    positive gain, as in the paper's examples.
    """
    x1, x2, x3 = x[0], x[1], x[2]
    return (-x1 - 2.0 * x2 - 1.5 * x3 + 0.5 * math.sin(x1) * x2
            + (1.5 + math.cos(x1)) * (u + 0.2 * math.tanh(u)) + d)


class RK4Work(NamedTuple):
    """Work arrays of one RK4 step over a state of size N: the four slopes and a stage point."""

    k1: np.ndarray
    k2: np.ndarray
    k3: np.ndarray
    k4: np.ndarray
    stage: np.ndarray


def rk4_work(size: int) -> RK4Work:
    return RK4Work(*(np.zeros(size) for _ in range(5)))


@register_jitable
def rk4_step(params: Any, t: float, s: np.ndarray, u: float, d: float, dt: float,
             w: RK4Work) -> None:
    """Classical RK4 over ``dt`` with u and d held, ``s`` advanced in place;
    :func:`plant_rhs` of ``params`` gives the derivative.

    Plain Python from Python (the generic loop, where a blow-up in ``math`` raises) and
    inlined into compiled code (:mod:`tspend.loop.fastloop`): one integrator, two callers.
    """
    h2 = 0.5 * dt
    N = s.size
    plant_rhs(params, t, s, u, d, w.k1)
    for i in range(N):
        w.stage[i] = s[i] + h2 * w.k1[i]
    plant_rhs(params, t + h2, w.stage, u, d, w.k2)
    for i in range(N):
        w.stage[i] = s[i] + h2 * w.k2[i]
    plant_rhs(params, t + h2, w.stage, u, d, w.k3)
    for i in range(N):
        w.stage[i] = s[i] + dt * w.k3[i]
    plant_rhs(params, t + dt, w.stage, u, d, w.k4)
    sixth = dt / 6.0
    for i in range(N):
        s[i] = s[i] + sixth * (w.k1[i] + 2.0 * w.k2[i] + 2.0 * w.k3[i] + w.k4[i])


@register_jitable
def chain_rhs(accel: Callable, t: float, s: np.ndarray, u: float, d: float,
              sdot: np.ndarray) -> None:
    """The chain of integrators (6): ``x_i' = x_{i+1}``, ``x_n' = accel(t, x, u, d)``."""
    n = s.size
    for i in range(n - 1):
        sdot[i] = s[i + 1]
    sdot[n - 1] = accel(t, s, u, d)


# Compiled code picks a plant's right-hand side by the type of its parameters: types that
# are module-level classes stay the same from one process to the next, so the compiled
# closed loop is cached on disk (a function passed as a value would not be).
class NonaffineChain(NamedTuple):
    """Example 1's plant, as compiled code knows it (no parameters)."""

    order: int = 2

    def rhs_into(self, t: float, s: np.ndarray, u: float, d: float, sdot: np.ndarray) -> None:
        chain_rhs(nonaffine_accel, t, s, u, d, sdot)

    def accel(self, t: float, x: np.ndarray, u: float, d: float) -> float:
        return nonaffine_accel(t, x, u, d)


class DuffingChain(NamedTuple):
    """Example 2's plant, as compiled code knows it (no parameters)."""

    order: int = 2

    def rhs_into(self, t: float, s: np.ndarray, u: float, d: float, sdot: np.ndarray) -> None:
        chain_rhs(duffing_accel, t, s, u, d, sdot)

    def accel(self, t: float, x: np.ndarray, u: float, d: float) -> float:
        return duffing_accel(t, x, u, d)


class ThirdOrderChain(NamedTuple):
    """The third-order plant, as compiled code knows it (no parameters)."""

    order: int = 3

    def rhs_into(self, t: float, s: np.ndarray, u: float, d: float, sdot: np.ndarray) -> None:
        chain_rhs(third_order_accel, t, s, u, d, sdot)

    def accel(self, t: float, x: np.ndarray, u: float, d: float) -> float:
        return third_order_accel(t, x, u, d)


#: parameter structure type -> its compiled right-hand side ``rhs(params, t, s, u, d, sdot)``;
#: a domain with its own compiled machine registers it here (the derived machines' ``DerivedRHS``)
COMPILED_RHS: dict[type, Callable] = {}


def plant_rhs(params: Any, t: float, s: np.ndarray, u: float, d: float,
              sdot: np.ndarray) -> None:
    """The right-hand side of the plant ``params`` stands for, into ``sdot``: in Python its
    ``rhs_into``; in compiled code chosen by the type of ``params`` (:func:`_plant_rhs`)."""
    params.rhs_into(t, s, u, d, sdot)


@overload(plant_rhs, jit_options=JIT)
def _plant_rhs(params, t, s, u, d, sdot):
    cls = params.instance_class if isinstance(params, types.BaseNamedTuple) else None
    if cls in COMPILED_RHS:
        rhs = COMPILED_RHS[cls]

        def impl(params, t, s, u, d, sdot):
            rhs(params, t, s, u, d, sdot)

        return impl
    if cls in _CHAIN_ACCEL:
        accel = _CHAIN_ACCEL[cls]

        def chain_impl(params, t, s, u, d, sdot):
            chain_rhs(accel, t, s, u, d, sdot)

        return chain_impl
    return None


class CompiledPlant(NamedTuple):
    """What a compiled closed loop needs to step a plant without Python.

    Inside ``@njit`` code: ``rk4_step(plant_rhs, params, clock[0], state, u, d, dt, work)``
    then ``clock[0] += dt``; ``state`` (the full state, x first, then hidden states) and
    ``clock`` are the plant's own arrays, so the plant is where the loop left it.
    """

    params: Any
    state: np.ndarray
    clock: np.ndarray
    work: RK4Work
    #: the full state is ``state[full_order]``
    full_order: np.ndarray


class AnalyticPlant(Plant):
    """A plant of the form (6), stepped by classical RK4 with u and d held constant.

    ``hidden_names`` extra states may ride along (the test oracle's cart, whose
    ``_rhs_params`` integrates them); the default view is the first ``order`` entries,
    ``extras`` reports the rest.  The full
    state is named ``x1 .. xn`` (then the hidden names) unless ``state_names`` says
    otherwise; ``full_order`` gives, for each entry of the full state, its place in the
    integrated vector ``s`` (identity unless a domain orders its state differently).
    """

    def __init__(self, accel: Accel, order: int, name: str = "analytic",
                 hidden_names: tuple[str, ...] = (), domain: str = "",
                 state_names: tuple[str, ...] = (), state_units: tuple[str, ...] = (),
                 full_order: tuple[int, ...] = ()) -> None:
        self.accel = accel
        self.order = int(order)
        self.name = name
        self.domain = domain or name
        self.hidden_names = hidden_names
        self._clock = np.zeros(1)
        self.s = np.zeros(self.order + len(hidden_names))
        self._work = rk4_work(self.s.size)
        self._names = state_names or (tuple(f"x{i + 1}" for i in range(self.order))
                                      + tuple(hidden_names))
        self._units = state_units or ("",) * len(self._names)
        self._full_order = np.asarray(full_order or range(self.s.size), dtype=np.intp)

    @property
    def state_names(self) -> tuple[str, ...]:
        return self._names

    @property
    def state_units(self) -> tuple[str, ...]:
        return self._units

    def full_state(self) -> np.ndarray:
        return self.s[self._full_order]

    @property
    def full_order(self) -> np.ndarray:
        """Index of each full-state entry in the integrated vector (for compiled loops)."""
        return self._full_order

    def default_task(self) -> TaskDefaults:
        return TaskDefaults(view=tuple(self.state_names[i] for i in self._full_order.argsort()
                                       [: self.order]))

    @property
    def t(self) -> float:
        return float(self._clock[0])

    def reset(self, x0: np.ndarray) -> None:
        x0 = np.asarray(x0, dtype=float)
        if x0.shape != (self.order,):
            raise ValueError(f"{self.name}: initial state must have {self.order} entries, got {x0.shape}")
        self.s[:] = 0.0
        self.s[: self.order] = x0
        self._clock[0] = 0.0

    def rhs(self, t: float, s: np.ndarray, u: float, d: float) -> np.ndarray:
        """Full derivative: the chain of integrators, accel last, then hidden states."""
        sdot = np.empty_like(s)
        plant_rhs(self._rhs_params(), t, s, u, d, sdot)
        return sdot

    def _rhs_params(self) -> Any:
        return self

    def rhs_into(self, t: float, s: np.ndarray, u: float, d: float, sdot: np.ndarray) -> None:
        chain_rhs(self.accel, t, s[:self.order], u, d, sdot[:self.order])

    def step(self, u: float, d: float, dt: float) -> None:
        rk4_step(self._rhs_params(), self._clock[0], self.s, u, d, dt, self._work)
        self._clock[0] += dt

    def compiled(self) -> CompiledPlant | None:
        """The plant for a compiled closed loop (None for an ``accel`` compiled code does
        not know)."""
        chain = _CHAIN_OF.get(self.accel)
        if chain is None:
            return None
        return CompiledPlant(chain(), self.s, self._clock, self._work, self._full_order)

    def extras(self) -> dict[str, float]:
        return {name: float(v) for name, v in zip(self.hidden_names, self.s[self.order:])}

    def extras_index(self) -> np.ndarray:
        """The hidden states' places in the full state."""
        return np.argsort(self._full_order)[self.order:].astype(np.intp)


_CHAIN_ACCEL: dict[type, Callable] = {NonaffineChain: nonaffine_accel,
                                      DuffingChain: duffing_accel,
                                      ThirdOrderChain: third_order_accel}
_CHAIN_OF = {accel: chain for chain, accel in _CHAIN_ACCEL.items()}


def _view_accel_of(accel: Callable) -> Callable:
    """A chain's ``accel`` as a compiled view model's ``f(model, t, x, u, d)``."""

    @register_jitable
    def view_accel(model, t, x, u, d):
        return accel(t, x, u, d)

    return view_accel


# the chains' view is their whole state: the controllers' model is the plant's own f
COMPILED_VIEW_ACCEL.update({chain: _view_accel_of(accel) for chain, accel in _CHAIN_ACCEL.items()})


# -- the paper's chain plants as domains -------------------------------------------------
class ChainDomain(Domain):
    """One of the paper's chain plants (6): a single analytic kind whose whole state is the
    task's view, with the plant's own ``f`` as the controllers' model."""

    def __init__(self, name: str, accel: Accel, order: int, affine_in_u: bool,
                 switching_gain: float, labels: PlantLabels) -> None:
        self.name, self.accel, self.affine_in_u = name, accel, affine_in_u
        self.switching_gain = switching_gain
        self.labels = labels
        self.task = TaskDefaults(view=tuple(f"x{i + 1}" for i in range(order)))
        self.kinds = {name: Backend(AnalyticPlantConfig, lambda cfg, path: self.make())}

    def make(self) -> AnalyticPlant:
        return AnalyticPlant(self.accel, self.order, self.name)

    def plant_model(self, scenario: "Scenario", machine: Plant) -> PlantModel:
        chain = _CHAIN_OF.get(self.accel)
        return PlantModel(self.name, self.order, self.accel, affine_in_u=self.affine_in_u,
                          x_op=(0.0,) * self.order, switching_gain=self.switching_gain,
                          compiled=chain() if chain is not None else None)


# sliding mode's k is a margin over the model error |Delta| on the paper's operating
# regions (docs/controllers.md): Example 1 2 (disturbance 0.1 plus the input gain's
# variation away from the origin), Duffing 20 (12 cos t and x1^3 with |x1| <= 1.5 are
# outside the linear model: about 15.5), the third-order plant 2
NONAFFINE = ChainDomain("nonaffine", nonaffine_accel, 2, False, 2.0, PlantLabels(
    (Quantity("x1", "", "state"), Quantity("x2", "", "state")), Quantity("u", "", "control"), {}))
DUFFING = ChainDomain("duffing", duffing_accel, 2, True, 20.0, PlantLabels(
    (Quantity("x", "", "Duffing position"), Quantity("x'", "", "Duffing velocity")),
    Quantity("u", "", "forcing control"), {}))
THIRD_ORDER = ChainDomain("third_order", third_order_accel, 3, False, 2.0, PlantLabels(
    (), Quantity("u", "", "control"), {}).padded(3))

#: the paper's chain domains
DOMAINS: tuple[ChainDomain, ...] = (NONAFFINE, DUFFING, THIRD_ORDER)


def nonaffine_plant() -> AnalyticPlant:
    return NONAFFINE.make()


def duffing_plant() -> AnalyticPlant:
    return DUFFING.make()


def third_order_plant() -> AnalyticPlant:
    return THIRD_ORDER.make()
