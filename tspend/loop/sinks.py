"""What the closed-loop runner hands to whoever listens: the sink protocol.

The runner knows nothing of Rerun, files or plots.  It fills fixed-size blocks of
per-step samples and passes each block to every sink; every ``inner_every`` steps it
also passes a snapshot of the controller's inner state (membership curves, firing
strengths).  Sinks: the metrics accumulator, the in-memory history for the Python API,
the Rerun recorder.

Per-step block (``Block.data``), every array's first axis is the step within the block.
The runner writes these keys for every controller:

=============  ==========  ==========================================================
key            shape       meaning
=============  ==========  ==========================================================
``t``          (k,)        simulated time of the sample (s), at the start of the step
``x``          (k, n)      plant state read by the controller
``ref``        (k, n+1)    reference r, r', ..., r^(n)
``e``          (k, n)      tracking error e = x - r (first n entries of ref)
``u``          (k,)        control returned by the controller (the command; the plant
                           applies it clipped to ``RunInfo.u_lo``, ``u_hi``)
``d``          (k,)        disturbance d_d applied over the step
``NAME``       (k,)/(k,w)  each diagnostic the controller declares
                           (:class:`tspend.controllers.base.Diagnostic`), e.g. the paper
                           controller's ``u_s``, ``d_hat``, ``e_delta``, ``V``, ``p``,
                           ``norm_P``, ``norm_q``, ``min_b``
``state``      (k, N)      the plant's full state (``RunInfo.state_names`` order)
``extra/NAME`` (k,)        plant extras (cart_pos, cart_vel for cart-poles)
=============  ==========  ==========================================================
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol

import numpy as np

from tspend.plants.drawing.base import Drawing
from tspend.task import Bound

if TYPE_CHECKING:
    # an annotation only: importing tspend.controllers here runs its registry, whose paper
    # kind imports this module back (``import tspend.recorder`` failed on a fresh interpreter)
    from tspend.controllers.base import Diagnostic


@dataclass(frozen=True)
class FuzzyInputInfo:
    """One antecedent input as a recorder needs to draw it."""

    name: str              # "x_o1", "u_o", "e_delta", "|x|"
    lo: float
    hi: float
    terms: tuple[str, ...]  # ("NB", "NS", "Z", "PS", "PB")


@dataclass(frozen=True)
class RunInfo:
    """Everything a sink needs to know before the first block."""

    scenario_name: str
    scenario_text: str
    scenario_path: str
    seed: int
    version: str
    plant_kind: str
    order: int
    dt: float
    duration: float
    steps: int
    #: the paper controller's antecedent inputs (empty for controllers without rule bases)
    model_inputs: tuple[FuzzyInputInfo, ...] = ()
    compensator_inputs: tuple[FuzzyInputInfo, ...] = ()
    extras: tuple[str, ...] = ()
    #: which controller runs, and the diagnostics it declared
    controller_kind: str = ""
    diagnostics: tuple[Diagnostic, ...] = ()
    #: what to draw of the plant in 3D (its domain's drawing), or None
    drawing: Drawing | None = None
    #: the plant's full state (``state`` in a block): names and units, and the task's view
    state_names: tuple[str, ...] = ()
    state_units: tuple[str, ...] = ()
    view: tuple[str, ...] = ()
    #: the task's bounds on the full state (rail ends, joint limits, fall angle)
    bounds: tuple[Bound, ...] = ()
    #: u's unit as the plant's model gives it ("" = the domain's label)
    input_unit: str = ""
    #: where u is not the force the actuator applies (a geared motor's ctrl, a voltage):
    #: that force's unit and the force per unit of u at rest ("" and 1: u is the force)
    force_unit: str = ""
    force_per_unit: float = 1.0
    #: the actuator's range: the plant applies ``u`` (the command) clipped to it
    #: (:func:`tspend.loop.simulation.input_range`); +-inf: no limit
    u_lo: float = -math.inf
    u_hi: float = math.inf


@dataclass(frozen=True)
class Block:
    """A run of consecutive steps; arrays are views the sink must copy if it keeps them."""

    start: int                      # index of the first step
    data: dict[str, np.ndarray]


@dataclass(frozen=True)
class InnerSnapshot:
    """The controller's inner state at one instant (decimated)."""

    t: float
    step: int
    #: per model input: (grid (G,), curves (T, G), operating value z_j, memberships (T,))
    model_sets: tuple[tuple[np.ndarray, np.ndarray, float, np.ndarray], ...]
    compensator_sets: tuple[tuple[np.ndarray, np.ndarray, float, np.ndarray], ...]
    firing: np.ndarray              # (h,) normalised firing strengths w^i (12)
    compensator_firing: np.ndarray  # (h_d,) tau^i (23)
    consequents: np.ndarray         # (h, n+1) p_k^i
    q: np.ndarray                   # (h_d,) compensator consequents


@dataclass(frozen=True)
class RunEnd:
    """How the run ended, with the metrics of what was simulated."""

    status: str                 # "completed" | "diverged" | "interrupted" | "failed"
    message: str
    steps_done: int
    metrics: dict


class Sink(Protocol):
    def start(self, info: RunInfo) -> None: ...

    def block(self, block: Block) -> None: ...

    def inner(self, snap: InnerSnapshot) -> None: ...

    def finish(self, end: RunEnd) -> None: ...
