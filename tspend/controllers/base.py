"""The controller interface: what the runner, the metrics and the recorders need of any controller.

Once per sample a controller receives one :class:`Observation`: the time, the plant's
FULL named state (``state``, in the plant's ``state_names`` order), the task's view
``x`` (the tracked output and its derivatives, n entries: what the paper's controllers
see) and the reference with its derivatives ``ref = [r, r', ..., r^(n)]``;
:meth:`Controller.step` returns the scalar control ``u``.  Besides ``u`` it may report
named diagnostics every sample (its parts of ``u``, the estimates it adapts, its Lyapunov
or sliding variable): it declares them once as a tuple of :class:`Diagnostic`, each
naming the columns of the controller's ``diag`` vector that :meth:`Controller.step`
writes.  The runner copies ``diag`` after every sample and hands the columns to the
sinks under the diagnostic's name, so nothing downstream knows which controller
produced them.

:class:`Controller` is an abstract base class: ``reset`` and ``step`` are abstract, the
optional features (inner snapshots, fuzzy inputs, a compiled step, adapted parameters)
are methods with defaults, so nobody asks a controller with ``getattr``.

The runner itself provides ``t``, ``x``, ``ref``, ``e = x - r``, ``u`` and the disturbance
``d``; a diagnostic may not reuse those names (:data:`RESERVED`).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Callable, Iterable, NamedTuple

import numpy as np

if TYPE_CHECKING:
    from tspend.task.constraints import ConstraintSet
    from tspend.plants.domain import Domain

__all__ = ["CompiledController", "Controller", "Diagnostic", "Observation", "RESERVED", "chain_observation",
           "check_diagnostics", "diag_width", "diagnostics"]

#: block keys the runner writes itself; no diagnostic may take one of these names
RESERVED = ("t", "x", "ref", "e", "u", "d")


@dataclass(frozen=True)
class Diagnostic:
    """One named per-sample quantity in a controller's ``diag`` vector.

    ``start`` and ``width`` locate it in ``diag``; ``labels`` name its columns (one per
    column: ``("p_1", "p_2", "b_hat")``); ``panel`` groups diagnostics plotted together
    (the recorder draws one view per panel); ``unit`` is shown on the axis; ``log`` asks
    for a logarithmic axis (norms, Lyapunov functions); ``chattering`` marks a signal
    whose extremes must survive thinning (min/max aggregation).
    """

    name: str
    start: int
    width: int = 1
    labels: tuple[str, ...] = ()
    panel: str = ""
    unit: str = ""
    description: str = ""
    log: bool = False
    chattering: bool = False

    @property
    def columns(self) -> slice | int:
        """Where it sits in ``diag``: an index for a scalar, a slice for a vector."""
        return self.start if self.width == 1 else slice(self.start, self.start + self.width)

    @property
    def column_labels(self) -> tuple[str, ...]:
        if self.labels:
            return self.labels
        return (self.name,) if self.width == 1 else tuple(f"{self.name}_{i + 1}" for i in range(self.width))


def diagnostics(*specs: tuple[str, int] | tuple[str, int, dict]) -> tuple[Diagnostic, ...]:
    """Diagnostics laid out one after the other: ``diagnostics(("u_s", 1), ("p", 3, {...}))``.

    Each spec is ``(name, width)`` or ``(name, width, keywords of Diagnostic)``.
    """
    out, start = [], 0
    for spec in specs:
        name, width = spec[0], int(spec[1])
        extra = spec[2] if len(spec) > 2 else {}
        out.append(Diagnostic(name=name, start=start, width=width, **extra))
        start += width
    return tuple(out)


def diag_width(diags: Iterable[Diagnostic]) -> int:
    """The length ``diag`` must have to hold every diagnostic."""
    return max((d.start + d.width for d in diags), default=0)


def check_diagnostics(diags: Iterable[Diagnostic], diag: np.ndarray) -> None:
    """Raise ValueError when names clash or a diagnostic lies outside ``diag``."""
    seen: set[str] = set()
    for d in diags:
        if d.name in RESERVED or d.name.startswith("extra/"):
            raise ValueError(f"diagnostic name {d.name!r} is reserved for the runner")
        if d.name in seen:
            raise ValueError(f"diagnostic {d.name!r} declared twice")
        if d.labels and len(d.labels) != d.width:
            raise ValueError(f"diagnostic {d.name!r}: {len(d.labels)} labels for width {d.width}")
        if d.start < 0 or d.start + d.width > diag.size:
            raise ValueError(f"diagnostic {d.name!r} lies outside diag (size {diag.size})")
        seen.add(d.name)


class Observation(NamedTuple):
    """What a controller sees at one sample.

    ``t`` the sample's time (s); ``state`` the plant's full state (its ``state_names``,
    positions then velocities); ``x`` the task's view (n,): the tracked output and its
    derivatives (on the cart-pole ``[hinge, hinge_dot]``); ``ref`` (n+1,) the reference
    and its derivatives; ``names`` the full state's names.  The arrays are read-only views
    of the runner's (writing into one raises ``ValueError``): a controller that keeps one
    must copy it.  ``constraints``: the task's constraints over the full state and the
    input (:class:`tspend.task.constraints.ConstraintSet`: boxes and linear inequalities, each
    hard or soft, with their margins at any state; None when the caller has no task).
    """

    t: float
    state: np.ndarray
    x: np.ndarray
    ref: np.ndarray
    names: tuple[str, ...] = ()
    constraints: "ConstraintSet | None" = None

    def get(self, name: str) -> float:
        """The full state's entry called ``name`` (KeyError if the plant has none)."""
        try:
            return float(self.state[self.names.index(name)])
        except ValueError:
            raise KeyError(f"no state named {name!r} (states: {', '.join(self.names)})") from None


def chain_observation(x: np.ndarray, ref: np.ndarray, t: float = 0.0) -> Observation:
    """An observation whose full state is the view itself (``x1 .. xn``): for tests and
    tools that drive a controller without a plant."""
    x = np.asarray(x, dtype=float)
    return Observation(t, x, x, np.asarray(ref, dtype=float),
                       tuple(f"x{i + 1}" for i in range(x.size)))


class CompiledController(NamedTuple):
    """What a compiled closed loop needs to take one controller sample without Python.

    Inside an ``@njit`` function::

        u = c.step(c.settings, c.state, c.scratch, t, full, x, ref, dt, diag)

    with ``t`` and ``dt`` floats, ``full`` the full state and ``x`` (n,), ``ref`` (n+1,)
    float64 arrays (as in :class:`Observation`) and ``diag`` a float64 array of the
    controller's ``diag`` size.  ``state`` is the controller's own (stepping here adapts
    it); ``settings`` must be an instance of a module-level NamedTuple class, which
    compiled code dispatches on (:mod:`tspend.loop.fastloop`).

    ``law``: the kind's law written once over an array namespace
    (:func:`tspend.runtime.law.array_law`), with the step's arguments and returning
    ``(u, state)``; ``step`` is it behind the compiled loops' signature, and its JAX form
    (:func:`tspend.runtime.law.jax_form`) is what the mjx backend runs.  None: the
    kind has no JAX form.
    """

    step: Callable
    settings: Any
    state: Any
    scratch: Any
    law: Callable | None = None


_NO_DIAG = np.zeros(0)
_NO_DIAG.flags.writeable = False


class Controller(ABC):
    """A controller of order ``n``: one call of :meth:`step` per sample.

    Subclasses set ``order`` and define :meth:`reset` and :meth:`step`; everything else
    has a default (``kind``: the class's name; ``diagnostics``: none; ``diag``: empty).
    """

    #: the controller kind, as chosen on the command line (``second_type``, ``lqr``, ...)
    kind: str = ""
    #: plant order n: x has n entries, ref has n + 1
    order: int
    #: the per-sample diagnostics, located in ``diag``
    diagnostics: tuple[Diagnostic, ...] = ()
    #: written by every :meth:`step`; the runner copies it after each sample (default: an
    #: empty, read-only array, for a controller that declares no diagnostics)
    diag: np.ndarray = _NO_DIAG
    #: True when :meth:`snapshot` has an inner state to show (fuzzy sets, firing ...)
    has_snapshots: bool = False
    #: the controller's own sample period (s; 0 = every physics step): the runner calls
    #: :meth:`step` this often and holds ``u`` in between, unless ``run.control_period``
    #: says otherwise (MPC: 20 ms)
    sample_period: float = 0.0
    #: what the kind needs of the plant's domain (:data:`tspend.plants.domain.CAPABILITIES`:
    #: ``"view_model"``, ``"full_state"``, ``"symbolic_model"``): on a domain that does not
    #: provide every one the kind is refused before anything is built (one line, exit 2)
    needs: tuple[str, ...] = ()
    #: the domains the kind is made for (empty: every domain that provides :attr:`needs`)
    domains: tuple[str, ...] = ()
    #: what the kind guarantees, in one line (docs/controllers.md's table)
    guarantees: str = ""
    #: True when :meth:`before_start` checks the start (a predictive safety filter's
    #: admission): a rig then reads its state before START to check it there
    checks_start: bool = False
    #: the kind's settings dataclass, read from the scenario's ``[controllers.KIND]`` table
    #: (:mod:`tspend.controllers.settings`; the paper's kinds: ``[controller]``); None:
    #: the kind has no settings
    Settings: "type | None" = None

    @classmethod
    def from_scenario(cls, scenario: Any, machine: Any = None) -> "Controller":
        """The kind's controller for ``scenario``, not reset yet.  ``machine``: the
        nominal machine (a plant built from the scenario as written, before ``[randomize]``
        draws: :func:`tspend.loop.simulation.nominal_machine`) a kind that :attr:`needs`
        a model designs on; None for a kind that needs none.

        By default a plug-in's convention: ``cls(scenario, settings)`` when the class
        declares :attr:`Settings`, else ``cls(scenario)``; the built-in kinds override it.
        """
        if cls.Settings is None:
            return cls(scenario)  # type: ignore[call-arg]
        return cls(scenario, cls.settings_in(scenario))  # type: ignore[call-arg]

    @classmethod
    def settings_in(cls, scenario: Any) -> Any:
        """The settings the kind runs with on ``scenario``: its ``[controllers.KIND]``
        table, else the defaults of :attr:`Settings` (None: the kind has none)."""
        if cls.Settings is None:
            return None
        from tspend.controllers.settings import settings_for

        return settings_for(scenario, cls.Settings)

    @classmethod
    def unsupported(cls, domain: "Domain") -> str | None:
        """Why this kind cannot run on ``domain``, in words (None: it can)."""
        if cls.domains and domain.name not in cls.domains:
            return (f"it is made for the {', '.join(cls.domains)} domain"
                    f"{'s' if len(cls.domains) > 1 else ''} only")
        missing = [n for n in cls.needs if n not in domain.provides]
        if missing:
            from tspend.plants.domain import CAPABILITIES

            return "it needs " + " and ".join(CAPABILITIES.get(n, n) for n in missing)
        return None

    @abstractmethod
    def reset(self, rng: np.random.Generator) -> None:
        """Forget everything adapted and draw the initial parameters from ``rng``."""

    @abstractmethod
    def step(self, obs: Observation, dt: float) -> float:
        """One sample: the control u for the observation ``obs`` over sample time ``dt``."""

    def before_start(self, obs: Observation) -> str | None:
        """The start checked before any input, from ``obs`` (a rig calls it before START
        with the state it read then; else the first :meth:`step` may): why it is refused,
        or None.  By default nothing is checked."""
        return None

    def interrupted(self) -> None:
        """A signal cut the last :meth:`step` or :meth:`before_start` short and the run
        ends there: what that call found is not kept as a finding, since the code it cut
        may have turned the signal into an answer of its own (a solver's failure read as
        "no plan").  By default nothing is dropped."""

    def parameters(self) -> dict[str, np.ndarray]:
        """Copies of every adapted parameter (empty for a fixed controller)."""
        return {}

    def run_metrics(self) -> dict[str, Any]:
        """The controller's own metrics over the run so far, merged into the run's at its
        end (a safety filter's intervention and compute per sample; empty: none)."""
        return {}

    def snapshot(self, t: float, step: int, x: np.ndarray) -> Any:
        """The inner state for recorders after the sample at ``t``, a
        :class:`tspend.loop.sinks.InnerSnapshot` (None: nothing to show);
        asked for every ``run.snapshot_every`` seconds only when :attr:`has_snapshots`
        and a sink draws it."""
        return None

    def fuzzy_inputs(self) -> dict[str, tuple[Any, ...]]:
        """The rule bases' antecedent inputs (:class:`tspend.loop.sinks.FuzzyInputInfo`), so a
        recorder can lay out their views before the first snapshot (empty: no rule base)."""
        return {}

    def compiled(self) -> CompiledController | None:
        """The compiled step and its structures for a closed loop in numba (None: the
        generic loop calls :meth:`step`)."""
        return None
