"""What a plant domain is: the one object the rest of tspend asks about a kind of machine.

A *domain* (the cart-pole, the Furuta pendulum, the paper's chain plants) holds everything
its machine means, in its own module under ``tspend/plants/``: the equations, the roles of
its MJCF joints and how each backend is built, its linearisation and the model the
model-based controllers assume (:class:`PlantModel`), the drawing for Rerun
(:class:`Drawing`), labels and units (:class:`PlantLabels`), the default task
(:class:`TaskDefaults`) and the scenario configuration class of each plant kind.
:mod:`tspend.plants.registry` maps plant kinds and domain names to domains; the runner,
recorder, cross-check, effects and controllers ask the domain and name no concrete plant.
docs/architecture.md walks through writing one.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, NamedTuple

import numpy as np

from tspend.config import PlantConfig
from tspend.errors import ScenarioError
from tspend.plants.base import Plant, TaskDefaults  # TaskDefaults: re-exported

if TYPE_CHECKING:
    from tspend.config import Scenario

__all__ = ["Domain", "Backend", "Drawing", "PlantLabels", "PlantModel", "Quantity",
           "TaskDefaults", "FD_STEP", "project_root"]

#: relative step of the central differences of :class:`PlantModel`
FD_STEP = 1e-6

Accel = Callable[[float, np.ndarray, float, float], float]


class Quantity(NamedTuple):
    """One physical quantity as plotted: short symbol, unit, and what it is."""

    symbol: str
    unit: str = ""
    meaning: str = ""

    def with_unit(self, text: str | None = None) -> str:
        """``"theta (rad)"``, or ``text`` with this quantity's unit."""
        text = self.symbol if text is None else text
        return f"{text} ({self.unit})" if self.unit else text


class PlantLabels(NamedTuple):
    """The task's view x_1 .. x_n, the control and the extras of one domain."""

    states: tuple[Quantity, ...]
    control: Quantity
    extras: dict[str, Quantity]

    def padded(self, order: int) -> "PlantLabels":
        """These labels for ``order`` states: extra ones are named ``x<i>``."""
        states = tuple(self.states[:order]) + tuple(Quantity(f"x{i + 1}")
                                                    for i in range(len(self.states), order))
        return PlantLabels(states, self.control, self.extras)

    def extra(self, name: str) -> Quantity:
        return self.extras.get(name, Quantity(name))


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

    def f(self, t: float, x: np.ndarray, u: float) -> float:
        return self.accel(t, x, u, 0.0)

    def df_du(self, t: float, x: np.ndarray, u: float) -> float:
        h = FD_STEP * (1.0 + abs(u))
        return (self.accel(t, x, u + h, 0.0) - self.accel(t, x, u - h, 0.0)) / (2.0 * h)

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


class Drawing(ABC):
    """What a recorder draws of a plant in 3D: a static scene, then poses per frame.

    The recorder (:mod:`tspend.recorder.sink`) calls :meth:`log_static` once and
    :meth:`log_frames` with batches of frames; it knows nothing of the machine.
    """

    #: the 3D view's title
    title: str = "plant"

    @abstractmethod
    def log_static(self, rec: Any, world: str, shade: Callable[[tuple], tuple]) -> None:
        """Log the scene under entity ``world``; ``shade`` maps colours (overlaid runs)."""

    @abstractmethod
    def log_frames(self, rec: Any, world: str, times: Any, x: np.ndarray,
                   extras: dict[str, np.ndarray]) -> None:
        """Log the poses for the samples ``times`` (a Rerun time column) given the view
        ``x`` (N, n) and the plant's extras (N,) by name."""

    @abstractmethod
    def view(self, origin: str, suffix: str = "") -> Any:
        """The Rerun 3D view of ``origin``."""

    def document(self) -> dict[str, Any]:
        """Facts shown in the run's info document."""
        return {}


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

    @property
    def order(self) -> int:
        """The length n of the task's view: what the paper's controllers see."""
        return len(self.task.view)

    def model_file(self, cfg: PlantConfig) -> str:
        """The MJCF a configuration names (the domain's default for an ODE's)."""
        return self.default_model

    def model_path(self, scenario: "Scenario") -> Path:
        """The scenario's MJCF: as given, else next to the scenario, else the project's."""
        p = Path(self.model_file(scenario.plant))
        if p.is_absolute():
            return p
        bases = [Path.cwd()]
        if scenario.path and scenario.path != "<string>":
            bases.append(Path(scenario.path).resolve().parent)
        bases.append(project_root())
        for base in bases:
            if (base / p).is_file():
                return base / p
        return p

    def build(self, scenario: "Scenario", kind: str | None = None) -> Plant:
        """The scenario's plant, or the same machine on backend ``kind`` of this domain,
        not yet reset."""
        kind = kind or scenario.plant.kind
        if kind not in self.kinds:
            raise ScenarioError(f"plant kind {kind!r} is not a backend of domain {self.name!r} "
                             f"(its kinds: {', '.join(self.kinds)})")
        return self.kinds[kind].build(scenario.plant, self.model_path(scenario))

    @abstractmethod
    def plant_model(self, scenario: "Scenario") -> PlantModel:
        """The model the model-based controllers assume for the scenario's plant."""

    def linearisation(self, scenario: "Scenario") -> tuple[np.ndarray, np.ndarray] | None:
        """``(A, B)`` of the FULL state (``plant.state_names`` order) about the domain's
        equilibrium, or None when the domain has none beyond the view's."""
        return None

    def drawing(self, plant: Plant, scenario: "Scenario") -> Drawing | None:
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

    def inspect(self, model_path: str) -> tuple[dict[str, Any], list[str]]:
        """``(facts, departures)`` of an MJCF as this domain reads it (``tspend inspect``)."""
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


def project_root() -> Path:
    """The checkout that holds ``models/`` and ``scenarios/`` (the package's parent)."""
    return Path(__file__).resolve().parents[2]
