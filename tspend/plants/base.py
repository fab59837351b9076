"""The plant interface (Physics): what the closed loop, the task and the recorders need.

A plant is a machine driven by a scalar control ``u`` and a disturbance ``d_d``.  It
exposes its FULL state, named like MuJoCo's qpos then qvel: a joint's position is named
after the joint, its velocity ``<joint>_dot`` (the cart-pole: ``("slider", "hinge",
"slider_dot", "hinge_dot")`` on both backends; the paper's chain plants ``("x1", "x2")``).
The paper's companion-form view (the tracked output and its derivatives, ``order``
entries) is the task's business (:mod:`tspend.task`: ``full_state()[task.view_index]``).

:class:`Plant` is an abstract base class: what every plant must define is abstract, the
optional parts (joints, inputs, parameters, extras, a compiled step ...) have defaults,
so nothing needs ``getattr`` to ask a plant for them.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Protocol, TypeVar, runtime_checkable

import numpy as np

if TYPE_CHECKING:
    from tspend.plants.articulated.machine import Machine
    from tspend.plants.mjcf import CartPoleParams

__all__ = ["CartPolePlant", "InputInfo", "JointInfo", "MachinePlant", "Plant", "TaskDefaults",
           "read_as", "velocity_name"]


def velocity_name(position: str) -> str:
    """The state name of a joint's velocity: ``hinge`` -> ``hinge_dot``."""
    return f"{position}_dot"


@dataclass(frozen=True)
class JointInfo:
    """One joint: ``kind`` "slide" or "hinge", the unit of its position, and its range
    ``(lo, hi)`` when it is limited (None: free)."""

    name: str
    kind: str
    unit: str
    range: tuple[float, float] | None = None


@dataclass(frozen=True)
class InputInfo:
    """One control input: its name, unit and bounds (+/-inf when unbounded).

    ``force_unit``: where ``u`` is not itself the force or torque the actuator applies (a
    geared motor, a gain other than 1, a voltage), that force's unit ("N", "N m"), and
    ``force_per_unit`` the force per unit of ``u`` at rest (gear x gain); "" and 1 where
    ``u`` is the force."""

    name: str
    unit: str = ""
    lo: float = -math.inf
    hi: float = math.inf
    force_unit: str = ""
    force_per_unit: float = 1.0


@dataclass(frozen=True)
class TaskDefaults:
    """A domain's default task: the view the paper's controllers see and when a run ends.

    ``view``: the state names the paper's controllers see (tracked output and its
    derivatives); ``fall_angle``: rad from upright that ends the run (0 = off), on the
    state ``pole``, an angle from the upright ("" when the domain balances nothing).
    A plant's :meth:`Plant.default_task` is its domain's, with the plant's own joint names.
    """

    view: tuple[str, ...]
    fall_angle: float = 0.0
    pole: str = ""
    #: every pole the fall angle applies to (() = just ``pole``): a chain of links
    poles: tuple[str, ...] = ()
    #: the real rig's stops on joints the model leaves free, ``(state, |limit|)``: a run
    #: that passes one ends ``joint_limit`` (the Furuta's arm on its cable)
    limits: tuple[tuple[str, float], ...] = ()

    @property
    def fallen_poles(self) -> tuple[str, ...]:
        """The states the fall angle bounds."""
        return self.poles or ((self.pole,) if self.pole else ())

    def renamed(self, names: dict[str, str]) -> "TaskDefaults":
        """This task with state names replaced by ``names`` (a plant's own joint names)."""
        return TaskDefaults(tuple(names.get(v, v) for v in self.view), self.fall_angle,
                            names.get(self.pole, self.pole),
                            tuple(names.get(p, p) for p in self.poles),
                            tuple((names.get(n, n), v) for n, v in self.limits))


class Plant(ABC):
    """A plant of order ``n`` (its default view) with a full named state.

    Subclasses define :meth:`reset`, :meth:`full_state`, :meth:`step`,
    ``order``, ``state_names`` and ``state_units``; everything else has a default.
    """

    #: the plant's domain ("cartpole", "duffing", "nonaffine", "third_order", ...)
    domain: str = ""
    #: plant kind name, used in messages
    name: str = "plant"
    #: plant order n: the default view has n entries
    order: int

    # -- the full state ---------------------------------------------------------------
    @property
    @abstractmethod
    def state_names(self) -> tuple[str, ...]:
        """The full state's names: positions, then velocities (like qpos then qvel)."""

    @property
    @abstractmethod
    def state_units(self) -> tuple[str, ...]:
        """The unit of each entry of the full state ("m", "rad", "m/s", "rad/s", "")."""

    @abstractmethod
    def full_state(self) -> np.ndarray:
        """The full state in :attr:`state_names` order; a copy the caller may keep."""

    @property
    def joints(self) -> tuple[JointInfo, ...]:
        """The machine's joints (none for an abstract ODE)."""
        return ()

    @property
    def inputs(self) -> tuple[InputInfo, ...]:
        """The control inputs with their bounds (default: one unbounded input ``u``)."""
        return (InputInfo("u"),)

    def parameters(self) -> dict[str, float]:
        """The physical parameters as simulated (empty for a plant that has none)."""
        return {}

    def mj_model(self) -> Any:
        """The compiled ``mujoco.MjModel`` a MuJoCo backend steps (None for any other)."""
        return None

    def default_task(self) -> TaskDefaults:
        """The domain's task: the tracked view, and the pole angle a fall is judged on."""
        return TaskDefaults(view=tuple(self.state_names[: self.order]))

    # -- stepping ---------------------------------------------------------------------
    @abstractmethod
    def reset(self, x0: np.ndarray) -> None:
        """Set the default view to ``x0`` (shape (n,)), the rest at rest, the clock to 0."""

    @abstractmethod
    def step(self, u: float, d: float, dt: float) -> None:
        """Advance by ``dt`` with ``u`` and ``d`` held constant (zero-order hold)."""

    def extras(self) -> dict[str, float]:
        """Quantities worth recording besides the task's view (cart position, ...)."""
        return {}

    # -- optional capabilities ---------------------------------------------------------
    @property
    def gain_sign(self) -> int:
        """Sign of d(x_n')/du at the operating point (the paper's Assumption 5)."""
        return 1

    def check_sample_time(self, dt: float) -> None:
        """Raise ScenarioError when the plant cannot be stepped at sample time ``dt``."""

    def departures(self, dt: float | None = None) -> list[str]:
        """How the plant departs from the paper's ODE (one line each; MJCF models)."""
        return []

    def unmodelled(self, dt: float | None = None) -> list[str]:
        """What the domain's ODE of this plant does not reproduce (the cross-check names
        only these); by default every departure."""
        return self.departures(dt)

    def constraint_active(self) -> str:
        """A constraint (a joint limit, a contact) the plant applies now, in words; ""
        when none (an ODE has none): the cross-check compares open loop up to it."""
        return ""

    def compiled(self) -> Any:
        """The plant for a compiled closed loop (:class:`tspend.plants.analytic.CompiledPlant`),
        or None: the generic loop steps it."""
        return None

    def compiled_mujoco(self, dt: float) -> Any:
        """A MuJoCo plant for a compiled closed loop (:class:`tspend.plants.mujoco_plant.MujocoLink`),
        or None."""
        return None

    def extras_index(self) -> np.ndarray | None:
        """Where each entry of :meth:`extras` sits in :meth:`full_state`, when every extra
        is a state entry (compiled loops record them from the full state); None when
        some are not."""
        return None if self.extras() else np.zeros(0, dtype=np.intp)

    def instability(self, t0: float) -> Exception | None:
        """The error a compiled MuJoCo step ended on (None: none)."""
        return None

    def underlying(self) -> "Plant":
        """The plant this one is seen through: itself; a wrapper (the effects' actuator,
        :class:`tspend.loop.effects.EffectsPlant`) returns the plant it wraps, so a domain reads
        its own plant's numbers without knowing of any wrapper."""
        return self


# -- what domains read of their own plants, beyond the loop's Plant ---------------------
@runtime_checkable
class MachinePlant(Protocol):
    """A plant stepped over a derived articulated machine (both backends of every domain
    over :mod:`tspend.plants.articulated`): what its domain designs and draws from."""

    @property
    def machine(self) -> "Machine": ...

    @property
    def q0(self) -> tuple[float, ...]: ...


@runtime_checkable
class CartPolePlant(Protocol):
    """A cart-pole plant: the paper's numbers (M, m, l, J, the actuator's) read off its
    compiled model, which a run may change (``[effects.change]``: a payload picked up)."""

    @property
    def params(self) -> "CartPoleParams": ...

    def set_params(self, params: "CartPoleParams") -> None: ...


ReadAs = TypeVar("ReadAs")


def read_as(plant: Plant, protocol: type[ReadAs]) -> ReadAs:
    """``plant`` (the plant behind any wrapper: :meth:`Plant.underlying`) as ``protocol``,
    what the caller reads of it; TypeError naming both when it is not one (a domain asked
    about another domain's plant: a bug, not a user's mistake)."""
    inner = plant.underlying()
    if not isinstance(inner, protocol):
        raise TypeError(f"{type(inner).__name__} is not a {protocol.__name__}")
    return inner
