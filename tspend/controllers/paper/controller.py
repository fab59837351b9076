"""The second type adaptive fuzzy controller: T-S model + compensator + control law (19).

:func:`controller_step` is one controller sample, composed of the compiled functions of
each concept's module:

1. ``e = x - r``, ``e_Delta = e^T Gamma b_e`` (:mod:`tspend.controllers.paper.control_law`);
2. the operating point: fixed ``(x_o, u_o)``, or state-following ``x_o = x`` and
   ``u_o = fraction * u(previous sample)`` (Example 3's ``u_o = u(t)/2`` is an algebraic
   loop; the previous sample breaks it, docs/paper-notes.md section 6);
3. the T-S model's firing (12) and p (9) at ``z = [x_o; u_o]`` (:mod:`tspend.controllers.paper.rules`,
   :mod:`tspend.controllers.paper.ts_model`), the compensator's d_hat and u_s (21)-(23)
   (:mod:`tspend.controllers.paper.compensator`);
4. u from (19);
5. the diagnostics, of the parameters the sample used;
6. the adaptive laws (25)-(27) and the control-point laws, every rate from the
   pre-update parameters, integrated by forward Euler over the sample time as a digital
   controller does, with the projections (Assumptions 4-5) after the consequent update.

Its data are three named structures: :class:`Settings` (constants), :class:`State`
(everything adapted, updated in place) and :class:`Scratch` (per-sample work arrays,
which also hold the sample's firing for snapshots).  :class:`AdaptiveFuzzyController`
is the :class:`tspend.controllers.base.Controller` around them; :meth:`~AdaptiveFuzzyController.compiled`
hands them to other compiled code (a closed loop in numba calls
``u = compiled_step(settings, state, scratch, t, full, x, ref, dt, diag)``, the interface of
:class:`tspend.controllers.base.CompiledController`; this controller uses the task's view
``x`` only).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Callable, NamedTuple

import numpy as np
from numba import njit, typeof, types
from numba.core import cgutils
from numba.core.extending import intrinsic
from numba.core.runtime.nrtdynmod import _meminfo_struct_type
from numba.experimental import structref

from tspend.controllers.paper import rules
from tspend.runtime.jit import JIT
from tspend.controllers.paper.bspline import BSplineInput
import tspend.runtime.xp as xp
from tspend.runtime.law import array_law
from tspend.controllers.paper.compensator import (CompensatorSettings, compensator_law,
    compensator_settings, estimate, sets_gradient, switching)
from tspend.config import ControllerConfig, SetSpec
from tspend.controllers.paper.control_law import (ControlLawSettings, control,
    control_law_settings, lyapunov_tracking, tracking_errors)
from tspend.controllers.base import CompiledController, Controller, Diagnostic, Observation
from tspend.controllers.paper.rules import Firing, fire_values, with_inputs
from tspend.loop.sinks import FuzzyInputInfo, InnerSnapshot
from tspend.controllers.paper.ts_model import (ModelSettings, antecedent_gradient, antecedent_law,
    consequent_law, initial_consequents, model_output, model_settings)

#: scalar diagnostics in ``diag``, in order; then e (n entries) and p (n + 1 entries)
DIAG_SCALARS = ("u", "u_s", "d_hat", "e_delta", "V", "norm_P", "norm_q", "min_b")


def diag_layout(n: int) -> dict[str, slice | int]:
    """Where each diagnostic sits in the ``diag`` vector of an order-n controller."""
    layout: dict[str, slice | int] = {k: i for i, k in enumerate(DIAG_SCALARS)}
    s = len(DIAG_SCALARS)
    layout["e"] = slice(s, s + n)
    layout["p"] = slice(s + n, s + 2 * n + 1)
    return layout


def diag_size(n: int) -> int:
    return len(DIAG_SCALARS) + 2 * n + 1


def paper_diagnostics(n: int) -> tuple[Diagnostic, ...]:
    """The per-sample diagnostics of the paper controller, as the runner sees them.

    ``u`` and ``e`` are in ``diag`` too (the step writes them) but the runner records
    those itself, so they are not declared.
    """
    L = diag_layout(n)
    p = L["p"]
    return (
        Diagnostic("u_s", L["u_s"], panel="compensator", unit="N",
                   description="compensator part of u (21)", chattering=True),
        Diagnostic("d_hat", L["d_hat"], panel="disturbance", unit="",
                   description="compensator estimate of the lumped uncertainty (23)", chattering=True),
        Diagnostic("e_delta", L["e_delta"], panel="error", description="e^T Gamma b_e"),
        Diagnostic("V", L["V"], panel="lyapunov", log=True,
                   description="tracking part of the Lyapunov function (28), 1/2 e^T Gamma e"),
        Diagnostic("norm_P", L["norm_P"], panel="norms", log=True,
                   description="Frobenius norm of the consequents P"),
        Diagnostic("norm_q", L["norm_q"], panel="norms", log=True,
                   description="norm of the compensator consequents q"),
        Diagnostic("min_b", L["min_b"], panel="norms",
                   description="min over rules of p_{n+1}^i (>= b_min under projection)"),
        Diagnostic("p", p.start, p.stop - p.start,
                   labels=tuple(f"p_{i + 1}" for i in range(n)) + ("b_hat",), panel="params",
                   description="model output p_1 .. p_{n+1} of (9); b_hat = p_{n+1}"),
    )


def _input(name: str, spec: SetSpec, cfg: ControllerConfig) -> BSplineInput:
    return BSplineInput(name, spec.lo, spec.hi, spec.terms, cfg.control_points, cfg.bspline_order)


def model_inputs(cfg: ControllerConfig) -> tuple[BSplineInput, ...]:
    """Antecedent inputs of the T-S model: x_o1 .. x_on, u_o."""
    xs = tuple(_input(f"x_o{j + 1}", s, cfg) for j, s in enumerate(cfg.state_sets))
    return xs + (_input("u_o", cfg.u_sets, cfg),)


def compensator_inputs(cfg: ControllerConfig) -> tuple[BSplineInput, BSplineInput]:
    return _input("e_delta", cfg.e_delta_sets, cfg), _input("|x|", cfg.x_norm_sets, cfg)


def input_info(inputs: tuple[BSplineInput, ...]) -> tuple[FuzzyInputInfo, ...]:
    return tuple(FuzzyInputInfo(i.name, i.lo, i.hi, i.term_names) for i in inputs)


# -- the named structures -----------------------------------------------------------------
class OperatingPoint(NamedTuple):
    """Where the T-S model is linearised: fixed, or following the state."""

    state_following: bool    # x_o = x, u_o = u_o_fraction * previous u
    x_o: np.ndarray          # (n,) fixed x_o
    u_o: float               # fixed u_o
    u_o_fraction: float


class DiagSlots(NamedTuple):
    """Where :func:`controller_step` writes each diagnostic in ``diag`` (:func:`diag_layout`)."""

    u: int
    u_s: int
    d_hat: int
    e_delta: int
    V: int
    norm_P: int
    norm_q: int
    min_b: int
    e: int                   # first of n
    p: int                   # first of n + 1


class Settings(NamedTuple):
    """Every constant of the controller."""

    law: ControlLawSettings
    model: ModelSettings
    compensator: CompensatorSettings
    operating_point: OperatingPoint
    slots: DiagSlots


class State(NamedTuple):
    """Everything the controller adapts, updated in place by every sample."""

    P: np.ndarray            # (h, n+1) consequents p_k^i of the T-S model
    C_model: np.ndarray      # (n+1, T_max, r) control points of the model's sets
    q: np.ndarray            # (h_d,) compensator consequents
    C_compensator: np.ndarray  # (2, T_max, r) control points of the compensator's sets
    last_u: np.ndarray       # (1,) the previous sample's u (state-following u_o)
    samples: np.ndarray      # (1,) samples taken since the last reset


class Scratch(NamedTuple):
    """Per-sample work arrays; after a sample they hold what produced its u."""

    model: Firing            # z = [x_o; u_o]
    compensator: Firing      # z = [e_Delta, ||x||]
    e: np.ndarray            # (n,) tracking error
    v: np.ndarray            # (n+1,) [x_delta; u - u_o]
    p: np.ndarray            # (n+1,) model output (9)


def settings_of(cfg: ControllerConfig) -> Settings:
    """The constants of the controller ``cfg`` describes."""
    n = cfg.order
    shape = cfg.shape_projection == "unimodal"
    L = diag_layout(n)
    return Settings(
        law=control_law_settings(cfg.lam, cfg.Q),
        model=model_settings(cfg, rules.grid(model_inputs(cfg), shape)),
        compensator=compensator_settings(cfg, rules.grid(compensator_inputs(cfg), shape)),
        operating_point=OperatingPoint(
            state_following=cfg.operating_point == "state",
            x_o=np.asarray(cfg.x_o, dtype=float) if cfg.x_o else np.zeros(n),
            u_o=float(cfg.u_o), u_o_fraction=float(cfg.u_o_fraction)),
        slots=DiagSlots(**{k: (v if isinstance(v, int) else v.start) for k, v in L.items()}))


def state_of(settings: Settings) -> State:
    """Zero parameters of the right shapes (:meth:`AdaptiveFuzzyController.reset` draws them)."""
    gm, gc = settings.model.grid, settings.compensator.grid
    n = settings.law.lam.size
    return State(P=np.zeros((gm.term_index.shape[0], n + 1)),
                 C_model=np.zeros(gm.peak_windows.shape[:2] + (gm.points,)),
                 q=np.zeros(gc.term_index.shape[0]),
                 C_compensator=np.zeros(gc.peak_windows.shape[:2] + (gc.points,)),
                 last_u=np.zeros(1), samples=np.zeros(1, dtype=np.int64))


def scratch_of(settings: Settings) -> Scratch:
    n = settings.law.lam.size
    return Scratch(model=rules.firing(settings.model.grid),
                   compensator=rules.firing(settings.compensator.grid),
                   e=np.zeros(n), v=np.zeros(n + 1), p=np.zeros(n + 1))


# -- one sample ---------------------------------------------------------------------------
@array_law
def operating_point(o: OperatingPoint, x: np.ndarray, last_u: float, z: np.ndarray,
                    v: np.ndarray) -> tuple:
    """``(u_o, z, v)``: ``z = [x_o; u_o]`` and ``v[:n] = x_delta = x - x_o``."""
    n = x.size
    if o.state_following:
        u_o = o.u_o_fraction * last_u
        for k in range(n):
            z = xp.put(z, k, x[k])
            v = xp.put(v, k, x[k] - x[k])
    else:
        u_o = o.u_o
        x_o = o.x_o
        for k in range(n):
            z = xp.put(z, k, x_o[k])
            v = xp.put(v, k, x[k] - x_o[k])
    z = xp.put(z, n, u_o)
    return u_o, z, v


@array_law
def record(slots: DiagSlots, P: np.ndarray, q: np.ndarray, e: np.ndarray, p: np.ndarray,
           diag: np.ndarray, u: float, u_s: float, d_hat: float, e_delta: float,
           V: float) -> np.ndarray:
    """The sample's diagnostics into ``diag``, of the parameters ``P``, ``q`` the sample
    used; returns ``(diag,)``."""
    n = e.size
    diag = xp.put(diag, slots.u, u)
    diag = xp.put(diag, slots.u_s, u_s)
    diag = xp.put(diag, slots.d_hat, d_hat)
    diag = xp.put(diag, slots.e_delta, e_delta)
    diag = xp.put(diag, slots.V, V)
    sq = 0.0
    bmin = np.inf
    for i in range(P.shape[0]):
        for k in range(n + 1):
            sq += P[i, k] * P[i, k]
        bmin = xp.where(P[i, n] < bmin, P[i, n], bmin)
    diag = xp.put(diag, slots.norm_P, math.sqrt(sq))
    sq = 0.0
    for i in range(q.size):
        sq += q[i] * q[i]
    diag = xp.put(diag, slots.norm_q, math.sqrt(sq))
    diag = xp.put(diag, slots.min_b, bmin)
    for k in range(n):
        diag = xp.put(diag, slots.e + k, e[k])
    for k in range(n + 1):
        diag = xp.put(diag, slots.p + k, p[k])
    return (diag,)


@array_law
def adapt(s: Settings, st: State, fm: Firing, fc: Firing, v: np.ndarray, e_delta: float,
          u: float, varpi: float, cvarpi: float, dt: float) -> State:
    """The adaptive laws (25)-(27) and the control-point laws, every rate from the
    parameters ``st`` the sample used; the state after them."""
    second_type = s.model.eta_mu != 0.0
    if second_type:
        fm = antecedent_gradient(s.model, st.P, v, fm, varpi)
    if s.compensator.adapt_sets:
        fc = sets_gradient(s.compensator, st.q, fc, cvarpi)
    P, = consequent_law(s.model, st.P, fm.w, v, e_delta, dt)
    C_model = st.C_model
    if second_type:
        C_model, = antecedent_law(s.model, C_model, fm, e_delta, dt)
    q, C_compensator = compensator_law(s.compensator, st.q, st.C_compensator, fc, e_delta, dt)
    return State(P, C_model, q, C_compensator, xp.put(st.last_u, 0, u),
                 xp.add(st.samples, 0, 1))


@array_law
def controller_law(settings: Settings, state: State, scratch: Scratch, t: float,
                   full: np.ndarray, x: np.ndarray, ref: np.ndarray, dt: float,
                   diag: np.ndarray) -> tuple:
    """``(u, state)``: one sample of the adaptive fuzzy controller at the task's view
    ``x`` (n,) with reference derivatives ``ref`` (n+1,) and sample time ``dt``; writes
    ``diag`` (:func:`diag_layout`).  The one implementation, for numba (``state`` and
    ``scratch`` updated in place) and JAX (:mod:`tspend.runtime.law`)."""
    s, st, w = settings, state, scratch
    n = w.e.size
    e_delta, e = tracking_errors(s.law, x, ref, w.e)
    u_o, z, v = operating_point(s.operating_point, x, st.last_u[0], w.model.z, w.v)
    varpi, fm = fire_values(s.model.grid, st.C_model, with_inputs(w.model, z))
    p, = model_output(fm.w, st.P, w.p)
    xx = 0.0
    for k in range(n):
        xx += x[k] * x[k]
    cz = xp.put(w.compensator.z, 0, e_delta)
    cz = xp.put(cz, 1, math.sqrt(xx))
    cvarpi, fc = fire_values(s.compensator.grid, st.C_compensator,
                             with_inputs(w.compensator, cz))
    d_hat = estimate(fc.w, st.q)
    u_s = switching(e_delta, s.compensator.boundary_layer) * d_hat
    u = control(p, v, ref[n], s.law.lam, e, u_s, u_o)
    v = xp.put(v, n, u - u_o)
    diag, = record(s.slots, st.P, st.q, e, p, diag, u, u_s, d_hat, e_delta,
                  lyapunov_tracking(s.law, e))
    return u, adapt(s, st, fm, fc, v, e_delta, u, varpi, cvarpi, dt)


@njit(**JIT)
def controller_step(settings: Settings, state: State, scratch: Scratch, x: np.ndarray,
                    ref: np.ndarray, dt: float, diag: np.ndarray) -> float:
    """:func:`controller_law`'s u at the view ``x`` (``state`` and ``scratch`` updated in
    place, ``diag`` written)."""
    return controller_law(settings, state, scratch, 0.0, x, x, ref, dt, diag)[0]


# -- the Python boundary ------------------------------------------------------------------
@structref.register
class _BoundType(types.StructRef):
    def preprocess_fields(self, fields):
        return tuple((name, types.unliteral(typ)) for name, typ in fields)


class _Bound(structref.StructRefProxy):
    """One controller's settings, state and scratch behind a single pointer.

    Unboxing the three structures costs ~60 ns per array on every call from Python (more
    than the whole step's arithmetic); a struct reference unboxes as one pointer.
    """


structref.define_proxy(_Bound, _BoundType, ["settings", "state", "scratch"])


@njit(cache=True)
def _bind(settings, state, scratch):
    return _Bound(settings, state, scratch)


@intrinsic
def _borrow(typingctx, bound):
    """The three structures of a :class:`_Bound`, borrowed: no reference count touched.

    Reading them through the struct reference's own attributes would increment and
    decrement the count of each of their ~35 arrays on every sample (atomic operations,
    ~0.5 us a sample); the proxy keeps them alive.  Only for functions compiled without
    reference counting (``_nrt=False``).  The payload pointer is read from the MemInfo
    as numba's own ``NRT_MemInfo_data_fast`` reads it.
    """
    names = ("settings", "state", "scratch")
    sig = types.Tuple([bound.field_dict[name] for name in names])(bound)

    def codegen(context, builder, signature, args):
        meminfo = cgutils.create_struct_proxy(bound)(context, builder, value=args[0]).meminfo
        info = builder.bitcast(meminfo, _meminfo_struct_type.as_pointer())
        payload = builder.load(cgutils.gep(builder, info, 0, 3))
        data_type = bound.get_data_type()
        layout = context.data_model_manager[data_type].get_value_type()
        data = cgutils.create_struct_proxy(data_type)(
            context, builder, ref=builder.bitcast(payload, layout.as_pointer()))
        return context.make_tuple(builder, signature.return_type,
                                  [getattr(data, name) for name in names])

    return sig, codegen


@njit(**JIT)
def _sample(bound, x, ref, dt, diag):
    settings, state, scratch = _borrow(bound)
    return controller_step(settings, state, scratch, x, ref, dt, diag)


_VECTOR = types.Array(types.float64, 1, "A")
_FLOAT64 = np.dtype(np.float64)


@njit(**JIT)
def compiled_step(settings: Settings, state: State, scratch: Scratch, t: float,
                  full: np.ndarray, x: np.ndarray, ref: np.ndarray, dt: float,
                  diag: np.ndarray) -> float:
    """:func:`controller_step` behind the compiled controllers' common signature
    (:class:`tspend.controllers.base.CompiledController`): the paper's controller sees the
    task's view ``x`` only, not the full state."""
    return controller_law(settings, state, scratch, t, full, x, ref, dt, diag)[0]


class FiringView(NamedTuple):
    """One rule base's inputs (m,), memberships (per input, (T_j,)) and firing (h,)."""

    z: np.ndarray
    mu: list
    w: np.ndarray


@dataclass(frozen=True)
class PaperDesign:
    """The paper controller's design (:func:`design`): the configuration, the law's frozen
    numbers (:func:`settings_of`: rule bases, grids, gains) and the two rule bases'
    antecedent inputs."""

    cfg: ControllerConfig
    settings: Settings
    inputs: dict


def design(cfg: ControllerConfig) -> PaperDesign:
    """The design of the controller ``cfg`` configures: pure (it needs no model)."""
    return PaperDesign(cfg, settings_of(cfg),
                       {"model": model_inputs(cfg), "compensator": compensator_inputs(cfg)})


class AdaptiveFuzzyController(Controller):
    """The controller of Theorem 1: a :class:`tspend.controllers.base.Controller`.

    Kind ``second_type`` (or ``first_type`` when the antecedents are fixed).  Build a new
    controller to change the configuration; the state arrays are updated in place and
    never replaced.  It uses the observation's task view ``obs.x`` (the paper's
    companion-form state); :meth:`sample` takes ``x`` and ``ref`` directly.
    """

    kind = "second_type"
    has_snapshots = True
    guarantees = ("bounded tracking error of the view (Theorem 1's Lyapunov argument), from "
                  "the sign of df/du only; nothing about joints outside the view")
    #: the settings: the scenario's ``[controller]`` table
    Settings = ControllerConfig
    #: what adapts ("second": consequents and membership functions; "first": consequents)
    adaptation = "second"

    @classmethod
    def settings_in(cls, scenario) -> ControllerConfig:
        """The scenario's ``[controller]`` settings with the kind's :attr:`adaptation`."""
        cfg = scenario.controller
        return cfg if cfg.adaptation == cls.adaptation else replace(cfg, adaptation=cls.adaptation)

    @classmethod
    def from_scenario(cls, scenario, machine=None) -> "AdaptiveFuzzyController":
        """The kind's controller on :meth:`settings_in`; it needs no model, so no
        ``machine``."""
        return make_controller(cls.settings_in(scenario))

    def __init__(self, design: PaperDesign) -> None:
        self.design = design
        self.cfg = cfg = design.cfg
        self.kind = "first_type" if cfg.adaptation == "first" else "second_type"
        self.n = self.order = n = cfg.order
        self.settings, self.inputs = design.settings, design.inputs
        self.state = state_of(self.settings)
        self.scratch = scratch_of(self.settings)
        self.diag = np.zeros(diag_size(n))
        self.layout = diag_layout(n)
        self.diagnostics = paper_diagnostics(n)
        self.sample = self._compiled_sample()
        sample = self.sample

        def step(obs: Observation, dt: float) -> float:
            return sample(obs.x, obs.ref, dt)

        step.__doc__ = AdaptiveFuzzyController.step.__doc__
        # an attribute, not the method: one Python call fewer per sample
        self.step = step  # type: ignore[method-assign]

    # -- set-up -----------------------------------------------------------------------
    def reset(self, rng: np.random.Generator) -> None:
        """Initial control points, then consequents (model, compensator) drawn from ``rng``."""
        cfg, s, st = self.cfg, self.settings, self.state
        st.C_model[:] = rules.initial_control_points(self.inputs["model"])
        st.C_compensator[:] = rules.initial_control_points(self.inputs["compensator"])
        st.P[:] = initial_consequents(s.model, rng, self.n, *cfg.init_consequents)
        st.q[:] = rng.uniform(*cfg.init_compensator, size=st.q.size)
        st.last_u[0] = 0.0
        st.samples[0] = 0

    initialise = reset

    def fuzzy_inputs(self) -> dict[str, tuple[FuzzyInputInfo, ...]]:
        """The antecedent inputs of the model's and the compensator's rule bases."""
        return {group: input_info(inputs) for group, inputs in self.inputs.items()}

    # -- one sample ---------------------------------------------------------------------
    def step(self, obs: Observation, dt: float) -> float:
        """One controller sample at the task's view ``obs.x`` (n,) with reference
        derivatives ``obs.ref`` (n+1,) (replaced in ``__init__`` by a closure over
        :meth:`sample`)."""
        return self.sample(obs.x, obs.ref, dt)  # pragma: no cover

    def sample(self, x: np.ndarray, ref: np.ndarray, dt: float) -> float:
        """One controller sample at state ``x`` (n,) with reference derivatives ``ref`` (n+1,).

        (Replaced in ``__init__`` by the closure of :meth:`_compiled_sample`.)
        """
        raise NotImplementedError  # pragma: no cover

    def _compiled_sample(self) -> Callable[[np.ndarray, np.ndarray, float], float]:
        """:meth:`sample` as a closure over the compiled entry: the fewest Python operations.

        The entry is the compiled overload of one fixed signature, called without numba's
        type dispatch (x and ref float64 vectors of any strides; anything else is
        converted first), on a struct reference holding settings, state and scratch.
        """
        bound = _bind(self.settings, self.state, self.scratch)
        sig = (typeof(bound), _VECTOR, _VECTOR, types.float64, types.Array(types.float64, 1, "C"))
        _sample.compile(sig)
        entry, diag, f8 = _sample.overloads[sig].entry_point, self.diag, _FLOAT64

        def step(x: np.ndarray, ref: np.ndarray, dt: float) -> float:
            if x.dtype is not f8 or ref.dtype is not f8 or x.ndim != 1 or ref.ndim != 1:
                x = np.ascontiguousarray(x, dtype=np.float64).reshape(-1)
                ref = np.ascontiguousarray(ref, dtype=np.float64).reshape(-1)
            return entry(bound, x, ref, dt, diag)

        step.__doc__ = AdaptiveFuzzyController.sample.__doc__
        return step

    def compiled(self) -> CompiledController:
        """The compiled step and this controller's structures, for a closed loop in numba."""
        return CompiledController(compiled_step, self.settings, self.state, self.scratch,
                                  controller_law)

    @property
    def u_prev(self) -> float:
        """The previous sample's u (the state-following operating point uses it)."""
        return float(self.state.last_u[0])

    # -- inspection ---------------------------------------------------------------------
    def parameters(self) -> dict[str, np.ndarray]:
        """Copies of every adapted parameter (for tests and checkpoints)."""
        st = self.state
        out = {"P": st.P.copy(), "q": st.q.copy()}
        for group, C in (("model", st.C_model), ("comp", st.C_compensator)):
            key = "model" if group == "model" else "compensator"
            out.update({f"C_{group}{j}": C[j, : inp.terms].copy()
                        for j, inp in enumerate(self.inputs[key])})
        return out

    def curves(self, group: str, j: int, points: int = 101) -> tuple[np.ndarray, np.ndarray]:
        """Membership curves of input j of ``group`` ("model" or "compensator") on a grid
        of its interval, with the adapted control points: (grid (G,), curves (T_j, G))."""
        inp = self.inputs[group][j]
        g = self.settings.model.grid if group == "model" else self.settings.compensator.grid
        C = self.state.C_model if group == "model" else self.state.C_compensator
        z = np.linspace(inp.lo, inp.hi, points)
        return z, rules.curves(g, C, j, z)

    def last_firing(self, x: np.ndarray | None = None) -> tuple[FiringView, FiringView]:
        """Inputs, memberships and firing strengths that produced the last sample's u.

        Model (z = [x_o; u_o]) then compensator (z = [e_Delta, ||x||]), inputs clamped
        to their intervals as the rule bases see them.  ``x`` is accepted for the
        protocol's sake; the sample's own ||x|| is kept.
        """
        if self.state.samples[0] == 0:
            raise RuntimeError("no controller sample taken yet: call step() first")
        out = []
        for group, f in (("model", self.scratch.model), ("compensator", self.scratch.compensator)):
            inputs = self.inputs[group]
            lo = np.array([i.lo for i in inputs])
            hi = np.array([i.hi for i in inputs])
            out.append(FiringView(np.clip(f.z, lo, hi),
                                  [f.mu[j, : inp.terms].copy() for j, inp in enumerate(inputs)],
                                  f.w.copy()))
        return out[0], out[1]

    def snapshot(self, t: float, step: int, x: np.ndarray) -> InnerSnapshot:
        """The controller's inner state after the sample at ``t``: membership curves (with
        the adapted control points), where the sample's inputs sat on them, and the
        firing strengths and consequents it used."""
        fir, cfir = self.last_firing(x)
        return InnerSnapshot(
            t=t, step=step,
            model_sets=self._sets("model", fir), compensator_sets=self._sets("compensator", cfir),
            firing=fir.w, compensator_firing=cfir.w,
            consequents=self.state.P.copy(), q=self.state.q.copy())

    def _sets(self, group: str, fir: FiringView) -> tuple:
        out = []
        for j in range(len(self.inputs[group])):
            grid, curves = self.curves(group, j)
            out.append((grid, curves, float(fir.z[j]), fir.mu[j]))
        return tuple(out)


class FirstTypeController(AdaptiveFuzzyController):
    """The kind ``first_type``: the paper's controller with the membership functions fixed
    (only the consequents adapt), the paper's implicit baseline."""

    kind = "first_type"
    adaptation = "first"


def make_controller(cfg: ControllerConfig) -> AdaptiveFuzzyController:
    """The paper controller for ``cfg`` (:func:`design`), its parameters zero (call
    ``reset(rng)``)."""
    return AdaptiveFuzzyController(design(cfg))
