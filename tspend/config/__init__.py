"""Typed, frozen configuration: what a scenario file maps onto.

Every field here has a key of the same name in the scenario TOML (see
``tspend/scenario/__init__.py`` for the loading and validation, and ``scenarios/`` for examples).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np

from tspend.runtime.bounds import MAX_BSPLINE_ORDER, MAX_CONTROL_POINTS
from tspend.config.signals import Disturbance, Reference


#: the largest closed-loop pole (rad/s) any kind's search reaches: the same cap on the same
#: quantity for every kind (PD's bandwidth, the poles of lambda (18), feedback
#: linearisation's and Wang's, the sliding surface's), so no kind is tuned against a lower
#: ceiling than another (issue 42); 1000 rad/s is the 1 ms sample rate's own limit
#: (pole x dt = 1). tspend.controllers.settings re-exports it.
POLE_CAP = 1000.0


def setting(default: Any, doc: str, *, kind: str = "number", low: float | None = None,
            strict: bool = False, length: str | None = None,
            choices: tuple[str, ...] = (), name: str | None = None,
            high: float | None = None, table: str | None = None, min_terms: int = 2,
            per_order: Callable[[int], Any] | None = None) -> Any:
    """A settings field of a controller kind (read by
    :func:`tspend.controllers.settings.read_settings`): ``kind`` is ``number``,
    ``integer``, ``bool``, ``choice``, ``string``, ``vector`` (``length`` ``"n"`` or
    ``"n-1"``), ``list`` (numbers, any length), ``interval`` (``[lo, hi]``), ``matrix``
    (n x n, symmetric positive definite), ``set`` (one table ``{terms, lo, hi}``) or
    ``sets`` (n such tables, each of at least ``min_terms`` terms); ``name`` is the key
    in the file when the field's name cannot be it (``lambda``); ``high``: the largest
    number or integer accepted (a setting that sizes work is bounded); ``table``: the
    sub-table the key lives in (``sets``); ``per_order``: the default for a plant of
    order n, where it depends on n."""
    meta = {"doc": doc, "kind": kind, "low": low, "strict": strict, "length": length,
            "choices": choices, "name": name, "high": high, "table": table,
            "min_terms": min_terms, "per_order": per_order}
    return field(default=default, metadata=meta)


def _identity_times_10(n: int) -> tuple[tuple[float, ...], ...]:
    return tuple(tuple(10.0 * (i == j) for j in range(n)) for i in range(n))


def _zeros(n: int) -> tuple[float, ...]:
    return (0.0,) * n


def companion(lam: Any) -> np.ndarray:
    """Lambda of the paper's (18): ones above the diagonal, last row ``-lambda``."""
    lam = np.asarray(lam, dtype=float)
    n = lam.size
    A = np.eye(n, k=1)
    A[-1, :] = -lam
    return A


def is_hurwitz(lam: Any) -> bool:
    """Whether ``s^n + lambda_n s^(n-1) + .. + lambda_1`` has all roots in Re s < 0 (the
    condition on ``[controller] lambda`` that :meth:`ControllerConfig.check` states)."""
    return bool(np.all(np.linalg.eigvals(companion(lam)).real < 0.0))


@dataclass(frozen=True)
class SetSpec:
    """``terms`` evenly spaced fuzzy sets on ``[lo, hi]`` for one antecedent input."""

    terms: int
    lo: float
    hi: float


@dataclass(frozen=True)
class ControllerConfig:
    """The adaptive fuzzy controller of section 3 (defaults: Example 3's design values)."""

    # what ``tspend tune`` searches for the paper's kinds, as every kind's settings class
    # declares it (a class attribute, not a field): the rates of (25)-(27), Q of Lemma 1 as
    # a scale of the identity, lambda of (18) as (s + p)^n, and the boundary layer of
    # (21) (0 = the paper's sign)
    SEARCH = {"eta": (1e-4, 0.1, "log"), "gamma": (0.01, 20.0, "log"),
              "Q": (0.1, 1000.0, "log", "diagonal"), "lambda": (0.2, POLE_CAP, "log", "poles"),
              "boundary_layer": (0.0, 1.0, "linear")}

    lam: tuple[float, ...] = setting(
        (1.0, 2.0), "lambda_1 .. lambda_n of (18): s^n + lambda_n s^(n-1) + .. + lambda_1 "
        "must be Hurwitz", kind="vector", length="n", name="lambda")
    Q: tuple[tuple[float, ...], ...] = setting(
        ((10.0, 0.0), (0.0, 10.0)), "Q of Lemma 1, symmetric positive definite (n x n)",
        kind="matrix", per_order=_identity_times_10)
    eta: float = setting(0.006, "consequent adaptation rate eta of (25)-(26)", low=0.0,
                         strict=True)
    eta_mu: float | None = setting(None, "antecedent (BMF control point) rate; none means "
                                         "eta.  Ignored by first type", low=0.0)
    gamma: float = setting(1.6, "compensator rate gamma of (27)", low=0.0, strict=True)
    adaptation: str = setting("second", '"second" adapts consequents and BMFs; "first" '
                                        'consequents only', kind="choice",
                              choices=("second", "first"))
    bspline_order: int = setting(3, "B-spline order d (3 = quadratic)", kind="integer", low=2,
                                 high=MAX_BSPLINE_ORDER)
    control_points: int = setting(9, "control points per set", kind="integer", low=1,
                                  high=MAX_CONTROL_POINTS)
    #: sets of x_o1 .. x_on (one entry per state), of u_o, of e_Delta and of ||x||
    state_sets: tuple[SetSpec, ...] = setting(
        (SetSpec(5, -0.7853981633974483, 0.7853981633974483),) * 2,
        "sets of x_o1 .. x_on, one table per state", kind="sets", name="states",
        table="sets", min_terms=1)
    u_sets: SetSpec = setting(SetSpec(3, -1000.0, 1000.0), "sets of u_o", kind="set",
                              name="u", table="sets")
    e_delta_sets: SetSpec = setting(SetSpec(5, -12.0, 12.0), "sets of e_Delta", kind="set",
                                    name="e_delta", table="sets")
    x_norm_sets: SetSpec = setting(SetSpec(5, 0.0, 1.0471975511965976), "sets of ||x||",
                                   kind="set", name="x_norm", table="sets")
    init_consequents: tuple[float, float] = setting(
        (-0.01, 0.01), "the interval the initial consequents p_k^i are drawn from",
        kind="interval")
    init_compensator: tuple[float, float] = setting(
        (-0.01, 0.01), "the interval the initial compensator consequents q^i are drawn from",
        kind="interval")
    b_min: float = setting(0.001, "Assumption 5: projection p_{n+1}^i >= b_min > 0 (or <= "
                                  "-b_min, see gain_sign)", low=0.0, strict=True)
    gain_sign: str = setting("plant", 'the known sign of df/du: "plant" (measured on the '
                                      'plant at run start), "positive" or "negative"; the '
                                      "projection keeps sign * p_{n+1}^i >= b_min",
                             kind="choice", choices=("plant", "positive", "negative"))
    norm_radius: float = setting(0.0, "Assumption 4: projection of each consequent column "
                                      "onto ||p_k|| <= radius (0 = off)", low=0.0)
    boundary_layer: float = setting(0.0, "boundary layer eps: sat(e_Delta/eps) instead of "
                                         "sign(e_Delta) in (21) (0 = sign)", low=0.0)
    leakage: float = setting(0.0, "leakage sigma in the compensator law (0 = the paper's "
                                  "(27))", low=0.0)
    leakage_mode: str = setting("sigma", '"sigma": leakage sigma q in (27); "e": Narendra\'s '
                                         "e-modification, sigma |e_Delta| q", kind="choice",
                                choices=("sigma", "e"))
    operating_point: str = setting("state", '"fixed" (x_o, u_o constant) or "state" (x_o = x, '
                                            "u_o = fraction * previous u)", kind="choice",
                                   choices=("fixed", "state"))
    x_o: tuple[float, ...] = setting((), "the fixed operating point x_o (zeros by default)",
                                     kind="vector", length="n", per_order=_zeros)
    u_o: float = setting(0.0, "the fixed operating point u_o")
    u_o_fraction: float = setting(0.5, "u_o = fraction * previous u (operating_point "
                                       '"state")')
    shape_projection: str = setting("off", '"unimodal": project the control points after each '
                                           "update so that every set stays unimodal and each "
                                           'input\'s sets stay ordered; "off": the paper\'s '
                                           "free sets", kind="choice",
                                    choices=("off", "unimodal"))

    def check(self, n: int) -> tuple[str, str] | None:
        """``(key, problem)`` when the settings do not fit a plant of order ``n``: lambda
        Hurwitz of length n, n state sets, enough control points, rule counts bounded."""
        import math

        from tspend.runtime.bounds import MAX_RULES

        if len(self.lam) != n:
            return "lambda", "missing (a list of numbers is required)"
        if not is_hurwitz(self.lam):
            return "lambda", (f"s^{n} + lambda_n s^{n - 1} + .. + lambda_1 must be Hurwitz "
                              f"(all roots in Re s < 0); {list(self.lam)} is not")
        if self.control_points < self.bspline_order:
            return "control_points", (f"must be >= bspline_order ({self.bspline_order}), got "
                                      f"{self.control_points}")
        if len(self.state_sets) != n:
            return "sets.states", f"missing: give {n} set tables, one per state"
        for key, specs, what in (("states", (*self.state_sets, self.u_sets), "T-S model (states x u)"),
                                 ("e_delta", (self.e_delta_sets, self.x_norm_sets),
                                  "compensator (e_delta x x_norm)")):
            rules = math.prod(s.terms for s in specs)
            if rules > MAX_RULES:
                return f"sets.{key}", (f"the {what} would have {rules} rules, more than "
                                       f"{MAX_RULES}; use fewer terms per set")
        return None

    @property
    def order(self) -> int:
        return len(self.lam)

    @property
    def b_sign(self) -> float:
        """+1 or -1: the side of zero the gain consequents are kept on ("plant" = +1 until
        the run resolves it)."""
        return -1.0 if self.gain_sign == "negative" else 1.0

    @property
    def antecedent_rate(self) -> float:
        if self.adaptation == "first":
            return 0.0
        return self.eta if self.eta_mu is None else self.eta_mu


def _positive(**more) -> dict:
    return {"low": 0.0, "strict": True, **more}


def _at_least_zero(**more) -> dict:
    return {"low": 0.0, **more}


@dataclass(frozen=True)
class PlantConfig:
    """What every plant kind has: its kind, initial state and divergence guard.

    Each kind has its own subclass (``tspend.plants.registry.PLANT_KINDS``); the scenario
    reader accepts exactly the fields of the kind's class, checked by the ``metadata``
    of each field (``low``/``strict`` bounds, ``choices``; ``own``: 0 stands for the
    machine's own value, so ``[randomize]`` may not draw it 0).
    """

    kind: str = "cartpole_mujoco"
    x0: tuple[float, ...] = (0.10471975511965977, 0.0)
    #: divergence guard: stop when any |x_i| exceeds this (0 = only non-finite values)
    state_bound: float = field(default=0.0, metadata=_at_least_zero())


@dataclass(frozen=True)
class AnalyticPlantConfig(PlantConfig):
    """The paper's analytic plants (nonaffine, duffing) and third_order: no parameters."""


@dataclass(frozen=True)
class ParameterChange:
    """A change of the machine at time ``at`` (a payload picked up); 0 keeps a value."""

    at: float = field(default=0.0, metadata=_at_least_zero())
    M: float = field(default=0.0, metadata=_at_least_zero())
    m: float = field(default=0.0, metadata=_at_least_zero())
    l: float = field(default=0.0, metadata=_at_least_zero())


@dataclass(frozen=True)
class OuterLoopConfig:
    """Cart centring by shaping the pole reference (docs/testbed.md); gains 0 = off."""

    #: theta_ref += k_x x_c + k_v x_c' (rad per m, rad per m/s), clipped to +/- max_angle
    k_x: float = 0.0
    k_v: float = 0.0
    max_angle: float = field(default=0.1, metadata=_positive())
    #: time constant of the first-order filter that makes the shaped reference smooth
    tau: float = field(default=0.5, metadata=_positive())


@dataclass(frozen=True)
class EffectsConfig:
    """Real-world effects between the controller and the plant; every one off by default."""

    #: actuator saturation |u| <= saturation (N; 0 = none) and rate limit (N/s; 0 = none)
    saturation: float = field(default=0.0, metadata=_at_least_zero())
    rate_limit: float = field(default=0.0, metadata=_at_least_zero())
    #: standard deviation of white sensor noise per state (empty = none), and its seed
    #: (its own stream: the controller's draws do not change)
    noise_std: tuple[float, ...] = ()
    noise_seed: int = 0
    #: measurement delay, in samples
    delay: int = 0
    #: the machine changes at a given time
    change: ParameterChange | None = None
    #: a rail of this half-length (m); the run ends with status "rail_end" (0 = endless)
    rail: float = field(default=0.0, metadata=_at_least_zero())
    #: cart-centring outer loop (off by default)
    outer_loop: OuterLoopConfig | None = None

    @property
    def active(self) -> bool:
        return self != EffectsConfig()


@dataclass(frozen=True)
class BoxConstraint:
    """``[task.constraints.box] NAME = {lo, hi, hard}``: ``lo <= NAME <= hi`` on a named state
    or the input (+/-inf: open).  ``hard``: crossing it ends the run ``constraint`` (a state's
    box only); soft: measured (tspend/task/constraints.py)."""

    lo: float = -float("inf")
    hi: float = float("inf")
    hard: bool = False


@dataclass(frozen=True)
class LinearConstraint:
    """``[task.constraints.linear] LABEL = {terms = {NAME = coefficient, ..}, max, min}``:
    ``min <= sum coefficient * NAME <= max`` over named states and the input (soft: measured,
    kept by the safety filter)."""

    terms: tuple[tuple[str, float], ...] = ()
    lo: float = -float("inf")
    hi: float = float("inf")


@dataclass(frozen=True)
class ConstraintsConfig:
    """``[task.constraints]``: the constraints a run is measured against and a safety filter
    keeps (tspend/task/constraints.py, docs/safety.md)."""

    #: the domain's own: every joint range and the rail (hard, as the task ends runs on
    #: them), the actuator's range (soft)
    defaults: bool = True
    #: (name, box) pairs: a state's or the input's box
    boxes: tuple[tuple[str, BoxConstraint], ...] = ()
    #: (label, inequality) pairs
    linear: tuple[tuple[str, LinearConstraint], ...] = ()


@dataclass(frozen=True)
class SafetyConfig:
    """``[safety]``: a safety filter between any controller and the plant (docs/safety.md)."""

    #: "off" or a name in the registry of safety filters (``tspend.controllers.SAFETY_FILTERS``,
    #: which the scenario reader checks it against): "cbf" (a control barrier function QP
    #: per sample), "mpsc" (predictive safety certification: a backup plan over a horizon
    #: ending in the LQR's invariant ellipsoid)
    filter: str = "off"
    #: class-K gains of the (high-order) barrier conditions, 1/s: psi_1 = h' + alpha_1 h,
    #: psi_1' + alpha_2 psi_1 >= 0 (a position box), h' + alpha_1 h >= 0 (a velocity's)
    alpha_1: float = field(default=2.0, metadata=_positive())
    alpha_2: float = field(default=4.0, metadata=_positive())
    #: how a position row (the rail, an arm's range) is kept: "hocbf", the second-order
    #: barrier (S1) with alpha_1, alpha_2; "braking", the stopping-distance barrier (S4),
    #: which leaves u alone until the room to brake at ``braking`` x the input's authority
    #: runs out (docs/safety.md)
    #: "lyapunov": the sublevel set s^T P s <= c of the full-state LQR's Riccati matrix P,
    #: c the largest whose ellipsoid lies inside every position row (S5): it keeps the
    #: whole machine (pole and cart) in a set the LQR can hold, not the cart alone
    barrier: str = field(default="hocbf", metadata={"choices": ("hocbf", "braking", "lyapunov")})
    #: (S4)'s deceleration as a share of what the input's range gives at rest
    braking: float = field(default=0.1, metadata=_positive())
    #: a fraction of each box's half-width kept as a margin against model mismatch and
    #: sampling (0.05: the filter keeps the state 5 % of the half-width inside)
    margin: float = field(default=0.05, metadata={"low": 0.0})
    #: weight of the (exact, linear) penalty on the slack that keeps the QP feasible when
    #: the barrier conditions and the input's range conflict; the slack is in shares of the
    #: input's range, and above 4 it is 0 whenever the conditions can all hold
    slack_weight: float = field(default=1000.0, metadata=_positive())
    #: CasADi conic solver of the QP (docs/safety.md: daqp, exact and silent, by default)
    solver: str = field(default="daqp", metadata={"choices": ("daqp", "qpoases", "osqp")})
    #: mpsc: the backup plan's intervals after its first (one control sample), and their
    #: length (s); the plan spans one sample + horizon x plan_period.  0: from the nominal
    #: machine's balancing LQR (docs/safety.md: 0.5 / its fastest closed-loop pole, and
    #: 3 time constants of its slowest, at most 40 intervals)
    horizon: int = field(default=0, metadata={"low": 0})
    plan_period: float = field(default=0.0, metadata=_at_least_zero())
    #: mpsc: RK4 steps per plan interval (0: at most 0.25 / the machine's fastest pole)
    substeps: int = field(default=0, metadata={"low": 0})
    #: mpsc: the filter's time per sample (ms): it answers within it with the certified
    #: plan it has when a better one is not certified in time (0: 0.8 x the control
    #: period; at most 1000)
    budget_ms: float = field(default=0.0, metadata=_at_least_zero())
    #: mpsc: end the run before its first input when no plan is certified from its start
    #: (status "refused", exit 4, with the certificate's reason: a rig's pre-flight check);
    #: false: such a start runs on the recovery plan, its samples counted uncertified
    refuse_unadmitted: bool = False


@dataclass(frozen=True)
class TaskConfig:
    """``[task]``: what the controllers track and what ends a run (tspend/task/__init__.py).

    Every field left at its default takes the plant domain's own (the cart-pole: view
    ``("hinge", "hinge_dot")``, fall at pi/2 from upright).
    """

    #: the state names the paper's controllers see: the tracked output and its
    #: derivatives up to the relative degree (empty = the domain's)
    view: tuple[str, ...] = ()
    #: rad from upright on the domain's pole angle that ends the run "fell"
    #: (None = the domain's: pi/2 for balancing domains; 0 = off)
    fall_angle: float | None = field(default=None, metadata=_at_least_zero())
    #: every limited joint's range ends the run ("rail_end" for a slide joint,
    #: "joint_limit" for another)
    joint_limits: bool = True
    #: (state name, bound) pairs: |value| > bound ends the run "state_bound"
    state_bounds: tuple[tuple[str, float], ...] = ()
    #: the goal, rad (or m): the tracked output within ``goal_angle`` of its reference
    #: from ``goal_by`` s to the end; a run that completes without it ends "not_reached"
    #: (0 = no goal: a run is judged by its bounds alone)
    goal_angle: float = field(default=0.0, metadata=_at_least_zero())
    #: s from the start by which the goal must hold (to the end of the run)
    goal_by: float = field(default=0.0, metadata=_at_least_zero())
    #: ``[task.constraints]``: boxes and linear inequalities over states and the input
    constraints: ConstraintsConfig = ConstraintsConfig()


@dataclass(frozen=True)
class RunConfig:
    duration: float = 20.0
    dt: float = 0.001
    seed: int = 1
    #: controller inner-state snapshots (BMF curves, firing) every this many seconds (0 = never)
    snapshot_every: float = 0.1
    #: divergence guard on |u| (0 = only non-finite values)
    control_bound: float = 0.0
    #: sampled control (issue 20): the controller runs every control_period s (0 = every
    #: dt, or the controller's own sample_period), its u held in between (zero-order
    #: hold); control_delay physics steps pass before a computed u is applied
    control_period: float = 0.0
    control_delay: int = 0
    #: the controller kind this scenario runs when none is chosen ("" = the paper's
    #: [controller]; e.g. "swingup")
    controller: str = ""


@dataclass(frozen=True)
class Scenario:
    name: str
    description: str
    run: RunConfig
    plant: PlantConfig
    #: a reference and a disturbance of ``tspend.config.signals`` (frozen dataclasses too)
    reference: Reference
    disturbance: Disturbance
    controller: ControllerConfig
    #: real-world effects (all off unless the scenario's [effects] table sets them)
    effects: EffectsConfig = EffectsConfig()
    #: the task: tracked view and termination (defaults from the plant's domain)
    task: TaskConfig = TaskConfig()
    #: where it came from, and its text (logged with every run)
    path: str = ""
    text: str = ""
    #: (dotted key, value) pairs applied on top of ``text`` (CLI --set, Python override)
    overrides: tuple = ()
    #: (kind, settings) pairs from the [controllers.KIND] tables (tspend.controllers.settings)
    controllers: tuple = ()
    #: what a seed draws of the plant ([randomize]; tspend.plants.randomize.Draw entries)
    randomize: tuple = ()
    #: ``[safety]``: the safety filter (off unless set)
    safety: SafetyConfig = SafetyConfig()
