"""The controller protocol: what the runner, the metrics and the recorders need of any controller.

A controller of order ``n`` maps the measured state ``x`` (n,) and the reference with its
derivatives ``ref = [r, r', ..., r^(n)]`` to a scalar control ``u``, once per sample.
Besides ``u`` it may report named diagnostics every sample (its parts of ``u``, the
estimates it adapts, its Lyapunov or sliding variable): it declares them once as a tuple
of :class:`Diagnostic`, each naming the columns of the controller's ``diag`` vector that
:meth:`Controller.step` writes.  The runner copies ``diag`` after every sample and hands
the columns to the sinks under the diagnostic's name, so nothing downstream knows which
controller produced them.

The runner itself provides ``t``, ``x``, ``ref``, ``e = x - r``, ``u`` and the disturbance
``d``; a diagnostic may not reuse those names (:data:`RESERVED`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable, Protocol, runtime_checkable

import numpy as np

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


@runtime_checkable
class Controller(Protocol):
    """A controller of order ``n``, one call of :meth:`step` per sample.

    Optional capabilities, looked up with ``getattr`` by whoever wants them:

    * ``snapshot(t, step, x) -> tspend.loop.sinks.InnerSnapshot``: the inner state for
      recorders (fuzzy sets, firing strengths, consequents), asked for every
      ``run.snapshot_every`` seconds only when a sink draws it;
    * ``fuzzy_inputs() -> dict[str, tuple[FuzzyInputInfo, ...]]``: the rule bases'
      antecedent inputs, so a recorder can lay out their views before the first snapshot.
    """

    #: the controller kind, as chosen on the command line (``second_type``, ``lqr``, ...)
    kind: str
    #: plant order n: x has n entries, ref has n + 1
    order: int
    #: the per-sample diagnostics, located in ``diag``
    diagnostics: tuple[Diagnostic, ...]
    #: written by every :meth:`step`; the runner copies it after each sample
    diag: np.ndarray

    def reset(self, rng: np.random.Generator) -> None:
        """Forget everything adapted and draw the initial parameters from ``rng``."""

    def step(self, x: np.ndarray, ref: np.ndarray, dt: float) -> float:
        """One sample: the control u for state ``x`` and reference derivatives ``ref``."""

    def parameters(self) -> dict[str, np.ndarray]:
        """Copies of every adapted parameter (empty for a fixed controller)."""
