"""Compiled (numba) kernel of one controller sample, and the backend factory.

:func:`controller_step` is exactly one call of
:meth:`tspend.controller.AdaptiveFuzzyController.step`, same equations and, as far as
practical, the same order of floating-point operations:

1. ``e = x - r``, ``e_Delta = Gamma[n-1] . e``;
2. the operating point: fixed ``(x_o, u_o)`` or ``x_o = x``, ``u_o = fraction * u_prev``;
3. each input's B-spline basis (3)-(4), only its ``d`` nonzero functions (the span is
   found on the precomputed knots, inputs clamped to ``[lo, hi]``, ``z = hi`` in the last
   non-empty span as in :func:`tspend.bspline.basis_matrix`; the Cox-de Boor recursion
   is that function's, restricted to the support), the memberships (5) clipped to
   [0, 1] and the unsaturated mask ``0 < B < 1``;
4. grid firing strengths with the guard of :mod:`tspend.rules`:
   ``w = (g + eps/h) / (varpi + eps)``, ``varpi`` the product of the membership sums;
5. ``p = w @ P`` (9), the compensator's ``d_hat`` and ``u_s`` (21)-(23), u by (19),
   ``v = [x_delta; u - u_o]``;
6. the diagnostics, recorded *before* the adaptation exactly as ``_record`` is called
   before ``_adapt`` in the numpy step (so ``norm_P``, ``norm_q`` and ``min_b`` are those
   of the parameters the sample used);
7. all rates from the pre-update parameters: (25)-(26), the second type control-point
   law ``eta_mu e_Delta dy/dc``, (27) with optional leakage, the compensator's
   control-point law; then forward Euler in place in the numpy order (P, projections,
   model control points, q, compensator control points).

Nothing is allocated per step: every constant is packed once by
:class:`CompiledController` and the scratch lives in one preallocated workspace.
Summation order inside dot products differs from BLAS, so results agree with the numpy
reference to rounding (~1e-15 relative per step), not bit for bit.  The kernels use
numba's ``error_model="numpy"``: a division by zero gives inf/nan as numpy does instead
of raising, and NaN inputs propagate (the runner's divergence guard sees them).

numba is optional: without it this module still imports, :func:`make_controller` with
``backend="auto"`` returns the numpy controller and only ``backend="numba"`` (or
constructing :class:`CompiledController`) raises.
"""

from __future__ import annotations

import math

import numpy as np

from .config import ControllerConfig
from .controller import DIAG_SCALARS, AdaptiveFuzzyController, FiringView
from .rules import VARPI_EPS

try:  # optional dependency
    from numba import njit

    HAVE_NUMBA = True
except ImportError:  # pragma: no cover - exercised only without numba
    HAVE_NUMBA = False

    def njit(*args, **kwargs):  # type: ignore[no-redef]
        """Stand-in so that the kernels below still define (as plain Python)."""
        if len(args) == 1 and callable(args[0]) and not kwargs:
            return args[0]
        return lambda f: f


BACKENDS = ("auto", "numba", "numpy")

# the kernel writes diag[0..7] in this order, then e (n) and p (n + 1)
if DIAG_SCALARS != ("u", "u_s", "d_hat", "e_delta", "V", "norm_P", "norm_q", "min_b"):
    raise ImportError("tspend.kernels is out of date with controller.DIAG_SCALARS")

# -- layout of the packed float constants ``fc`` -----------------------------------------
F_ETA = 0            # eta of (25)-(26)
F_ETA_MU = 1         # antecedent rate (0 = first type)
F_GAMMA = 2          # gamma of (27)
F_B_MIN = 3          # Assumption 5
F_RADIUS = 4         # Assumption 4 (0 = off)
F_BOUNDARY = 5       # boundary layer (0 = sign)
F_LEAKAGE = 6        # sigma (0 = off)
F_U_O = 7            # fixed u_o
F_U_O_FRACTION = 8   # state-following u_o = fraction * u_prev
F_STATE = 9          # 1.0: state-following operating point
F_ADAPT_COMP = 10    # 1.0: adapt the compensator's control points
F_EPS = 11           # rules.VARPI_EPS
F_VECTORS = 12       # then gamma_row (n), lam (n), x_o (n), Gamma (n*n, row-major)

# -- columns of the int table ``ic`` (one row per input: model inputs, then e_Delta, |x|)
I_TERMS = 0
I_POINTS = 1
I_ORDER = 2
I_SPAN = 3           # scratch: the span of the input's current value


# =========================================================================================
# kernels
# =========================================================================================
@njit(cache=True, nogil=True, error_model="numpy")
def _basis(zj, knots, J, r, d, ws):
    """Nonzero B-spline basis functions of input J at ``zj`` into ``ws[J, :d]``.

    Returns the span s: ``ws[J, l]`` is ``N_{s-d+1+l, d}(z)``.  The recursion is that of
    :func:`tspend.bspline.basis_matrix` (including the zero-length-span guard), evaluated
    only on the d functions that can be nonzero.
    """
    lo = knots[J, 0]
    hi = knots[J, r + d - 1]
    z = zj
    if z < lo:
        z = lo
    if z > hi:
        z = hi
    for l in range(d):
        ws[J, l] = 0.0
    if not (z >= lo):          # NaN: every basis function is zero, as in numpy
        return d - 1
    s = r - 1                  # z == hi: the last non-empty span
    if z < hi:
        for k in range(d - 1, r):
            if knots[J, k] <= z and z < knots[J, k + 1]:
                s = k
                break
    base = s - d + 1
    ws[J, d - 1] = 1.0         # order 1: the indicator of span s
    for k in range(2, d + 1):
        # order k: N_i = left_i N_i + right_i N_{i+1} for i = s-k+1 .. s; ascending i
        # overwrites N_i only after it was read, and N_{s+1} of order k-1 is zero
        for i in range(s - k + 1, s + 1):
            a = i - base
            left_den = knots[J, i + k - 1] - knots[J, i]
            right_den = knots[J, i + k] - knots[J, i + 1]
            left = (z - knots[J, i]) / left_den if left_den > 0.0 else 0.0
            right = (knots[J, i + k] - z) / right_den if right_den > 0.0 else 0.0
            nxt = ws[J, a + 1] if i < s else 0.0
            ws[J, a] = left * ws[J, a] + right * nxt
    return s


@njit(cache=True, nogil=True, error_model="numpy")
def _fire(z0, z1, z2row, j0, m, h, r0, C, knots, ic, tidx, ws, M, wrow, eps):
    """Memberships of inputs j0 .. j0+m-1 and the guarded firing strengths into ws[wrow].

    Input values: ``z0`` and ``z1`` for a two-input rule base (the compensator, with
    ``z2row < 0``), else ``ws[z2row, :m]``.  Returns varpi (plus eps), as ``Firing.varpi``.
    """
    prod = 1.0
    for j in range(m):
        J = j0 + j
        if z2row >= 0:
            zj = ws[z2row, j]
        elif j == 0:
            zj = z0
        else:
            zj = z1
        T = ic[J, I_TERMS]
        r = ic[J, I_POINTS]
        d = ic[J, I_ORDER]
        s = _basis(zj, knots, J, r, d, ws)
        ic[J, I_SPAN] = s
        base = s - d + 1
        total = 0.0
        for t in range(T):
            B = 0.0
            for l in range(d):
                B += C[j, t, base + l] * ws[J, l]
            mu = B
            if mu < 0.0:
                mu = 0.0
            if mu > 1.0:
                mu = 1.0
            ws[M + J, t] = mu
            ws[2 * M + J, t] = 1.0 if (B > 0.0 and B < 1.0) else 0.0
            total += mu
        prod = total if j == 0 else prod * total
    varpi = prod + eps
    floor = eps / h
    for i in range(h):
        g = ws[M + j0, tidx[r0 + i, 0]]
        for j in range(1, m):
            g = g * ws[M + j0 + j, tidx[r0 + i, j]]
        ws[wrow, i] = (g + floor) / varpi
    return varpi


@njit(cache=True, nogil=True, error_model="numpy")
def _membership_gradient(j0, m, h, r0, tidx, ws, M, wrow, yrow, varpi):
    """``dy/dmu`` of ``y = sum_i w^i y^i`` (``y^i`` in ``ws[yrow]``) into ws[3M + J].

    ``sum over rules using term s of input j of (y^i - y)/varpi * prod of the rule's
    other memberships`` (:meth:`RuleBase.output_gradient_wrt_memberships`).
    """
    y = 0.0
    for i in range(h):
        y += ws[wrow, i] * ws[yrow, i]
    for j in range(m):
        for t in range(ws.shape[1]):
            ws[3 * M + j0 + j, t] = 0.0
    for i in range(h):
        D = (ws[yrow, i] - y) / varpi
        for j in range(m):
            g = D
            for k in range(m):
                if k != j:
                    g = g * ws[M + j0 + k, tidx[r0 + i, k]]
            ws[3 * M + j0 + j, tidx[r0 + i, j]] += g


@njit(cache=True, nogil=True, error_model="numpy")
def _move_control_points(j0, m, C, ic, ws, M, rate, dt):
    """``C += dt * rate * (dy/dmu * unsaturated) * N`` on the support of each input."""
    for j in range(m):
        J = j0 + j
        T = ic[J, I_TERMS]
        d = ic[J, I_ORDER]
        base = ic[J, I_SPAN] - d + 1
        for t in range(T):
            gs = ws[3 * M + J, t] * ws[2 * M + J, t]
            for l in range(d):
                C[j, t, base + l] += dt * (rate * (gs * ws[J, l]))


@njit(cache=True, nogil=True, error_model="numpy")
def controller_step(x, ref, dt, u_prev, P, Cm, q, Cc, diag, fc, knots, ic, tidx, ws):
    """One sample of the adaptive fuzzy controller; returns u.

    ``P`` (h, n+1), ``Cm`` (m, T_max, r_max), ``q`` (h_d,), ``Cc`` (2, ., .) are the
    controller's own parameter arrays, updated in place; ``diag`` is written in the
    layout of :func:`tspend.controller.diag_layout`.  ``fc``, ``knots``, ``ic``, ``tidx``
    are the packed constants of :class:`CompiledController` and ``ws`` its workspace.
    """
    h = P.shape[0]
    n = P.shape[1] - 1
    m = Cm.shape[0]
    hc = q.shape[0]
    M = m + 2                       # model inputs, then e_Delta and |x|
    W_M = 4 * M                     # workspace rows after the per-input blocks
    W_Y = W_M + 1
    W_C = W_M + 2
    V_E = W_M + 3                   # e
    V_V = W_M + 4                   # v = [x_delta; u - u_o]
    V_P = W_M + 5                   # p
    V_Z = W_M + 6                   # z of the model = [x_o; u_o]
    eps = fc[F_EPS]
    o_grow = F_VECTORS
    o_lam = F_VECTORS + n
    o_xo = F_VECTORS + 2 * n
    o_G = F_VECTORS + 3 * n

    # 1. tracking error and e_Delta
    e_delta = 0.0
    for k in range(n):
        ek = x[k] - ref[k]
        ws[V_E, k] = ek
        e_delta += fc[o_grow + k] * ek
    # 2. operating point; x_delta goes into v[:n]
    state = fc[F_STATE] != 0.0
    if state:
        u_o = fc[F_U_O_FRACTION] * u_prev
        for k in range(n):
            ws[V_Z, k] = x[k]
            ws[V_V, k] = x[k] - x[k]
    else:
        u_o = fc[F_U_O]
        for k in range(n):
            ws[V_Z, k] = fc[o_xo + k]
            ws[V_V, k] = x[k] - fc[o_xo + k]
    ws[V_Z, n] = u_o
    # 3-5. T-S model: firing strengths and p = w @ P
    varpi = _fire(0.0, 0.0, V_Z, 0, m, h, 0, Cm, knots, ic, tidx, ws, M, W_M, eps)
    for k in range(n + 1):
        acc = 0.0
        for i in range(h):
            acc += ws[W_M, i] * P[i, k]
        ws[V_P, k] = acc
    # compensator on (e_Delta, ||x||)
    xx = 0.0
    for k in range(n):
        xx += x[k] * x[k]
    cvarpi = _fire(e_delta, math.sqrt(xx), -1, m, 2, hc, h, Cc, knots, ic, tidx, ws, M,
                   W_C, eps)
    d_hat = 0.0
    for i in range(hc):
        d_hat += ws[W_C, i] * q[i]
    bl = fc[F_BOUNDARY]
    if bl > 0.0:
        sw = e_delta / bl
        if sw < -1.0:
            sw = -1.0
        if sw > 1.0:
            sw = 1.0
    elif e_delta > 0.0:
        sw = 1.0
    elif e_delta < 0.0:
        sw = -1.0
    else:
        sw = e_delta          # sign(0) = 0 (and NaN stays NaN)
    u_s = sw * d_hat
    # control law (19)
    px = 0.0
    le = 0.0
    for k in range(n):
        px += ws[V_P, k] * ws[V_V, k]
        le += fc[o_lam + k] * ws[V_E, k]
    u = (-px + ref[n] - le - u_s) / ws[V_P, n] + u_o
    ws[V_V, n] = u - u_o

    # 6. diagnostics (before the adaptation, like _record before _adapt)
    diag[0] = u
    diag[1] = u_s
    diag[2] = d_hat
    diag[3] = e_delta
    V = 0.0
    for k in range(n):
        acc = 0.0
        for i in range(n):
            acc += (0.5 * ws[V_E, i]) * fc[o_G + i * n + k]
        V += acc * ws[V_E, k]
    diag[4] = V
    sq = 0.0
    bmin = np.inf
    for i in range(h):
        for k in range(n + 1):
            sq += P[i, k] * P[i, k]
        if P[i, n] < bmin:
            bmin = P[i, n]
    diag[5] = math.sqrt(sq)
    sq = 0.0
    for i in range(hc):
        sq += q[i] * q[i]
    diag[6] = math.sqrt(sq)
    diag[7] = bmin
    for k in range(n):
        diag[8 + k] = ws[V_E, k]
    for k in range(n + 1):
        diag[8 + n + k] = ws[V_P, k]

    # 7. rates from the pre-update parameters ...
    eta_mu = fc[F_ETA_MU]
    if eta_mu != 0.0:
        for i in range(h):                     # y^i = P^i . v
            acc = 0.0
            for k in range(n + 1):
                acc += P[i, k] * ws[V_V, k]
            ws[W_Y, i] = acc
        _membership_gradient(0, m, h, 0, tidx, ws, M, W_M, W_Y, varpi)
    adapt_comp = fc[F_ADAPT_COMP] != 0.0
    if adapt_comp:                             # d_hat = w_c @ q: y^i = q^i
        for i in range(hc):
            ws[W_Y, i] = q[i]
        _membership_gradient(m, 2, hc, h, tidx, ws, M, W_C, W_Y, cvarpi)
    # ... then forward Euler in the numpy order: P, projections, C_model, q, C_comp
    c = fc[F_ETA] * e_delta
    for i in range(h):
        wi = ws[W_M, i]
        for k in range(n + 1):
            P[i, k] += dt * (c * (wi * ws[V_V, k]))
    radius = fc[F_RADIUS]
    if radius > 0.0:
        for k in range(n + 1):
            sq = 0.0
            for i in range(h):
                sq += P[i, k] * P[i, k]
            nrm = math.sqrt(sq)
            if nrm < 1e-300:
                nrm = 1e-300
            f = radius / nrm
            if f > 1.0:
                f = 1.0
            for i in range(h):
                P[i, k] *= f
    b_min = fc[F_B_MIN]  # signed: Assumption 5 keeps the gains on b_min's side of it
    for i in range(h):
        if (P[i, n] - b_min) * b_min < 0.0:
            P[i, n] = b_min
    if eta_mu != 0.0:
        _move_control_points(0, m, Cm, ic, ws, M, eta_mu * e_delta, dt)
    ae = fc[F_GAMMA] * abs(e_delta)
    sigma = fc[F_LEAKAGE]
    if sigma > 0.0:
        gs = fc[F_GAMMA] * sigma
        for i in range(hc):
            q[i] += dt * (ae * ws[W_C, i] - gs * q[i])
    else:
        for i in range(hc):
            q[i] += dt * (ae * ws[W_C, i])
    if adapt_comp:
        _move_control_points(m, 2, Cc, ic, ws, M, ae, dt)
    return u


# =========================================================================================
# controller and factory
# =========================================================================================
class CompiledController(AdaptiveFuzzyController):
    """:class:`AdaptiveFuzzyController` whose :meth:`step` is one call of the numba kernel.

    The kernel updates the very parameter arrays of the numpy implementation
    (``model.P``, ``model.rules.C_all``, ``compensator.q``, ``compensator.rules.C_all``,
    ``diag``), so ``parameters()``, ``snapshot()``, ``initialise()`` and the runner work
    unchanged.  Constants (rates, projections, Gamma, knots, term-index tables) are
    packed in ``__init__``: change the configuration by building a new controller.
    ``model.P``, ``compensator.q`` and ``diag`` are looked up on every step, so they may
    be replaced by arrays of the same shape (float64, C order); the control points are
    updated in place through ``rules.C_all``, which must never be replaced (``rules.C``
    are views into it).
    """

    def __init__(self, cfg: ControllerConfig) -> None:
        if not HAVE_NUMBA:
            raise ImportError("the numba backend needs numba (pip install 'numba>=0.60')")
        super().__init__(cfg)
        n = self.n
        mrules, crules = self.model.rules, self.compensator.rules
        inputs = mrules.inputs + crules.inputs
        M = len(inputs)
        fc = np.zeros(F_VECTORS + 3 * n + n * n)
        fc[F_ETA] = self.eta
        fc[F_ETA_MU] = self.eta_mu
        fc[F_GAMMA] = self.gamma
        fc[F_B_MIN] = self.model.b_sign * self.model.b_min
        fc[F_RADIUS] = self.model.norm_radius
        fc[F_BOUNDARY] = self.compensator.boundary_layer
        fc[F_LEAKAGE] = self.compensator.leakage
        fc[F_U_O] = cfg.u_o
        fc[F_U_O_FRACTION] = cfg.u_o_fraction
        fc[F_STATE] = 1.0 if self.state_following else 0.0
        fc[F_ADAPT_COMP] = 1.0 if self.adapt_compensator_sets else 0.0
        fc[F_EPS] = VARPI_EPS
        o = F_VECTORS
        fc[o: o + n] = self.gamma_row
        fc[o + n: o + 2 * n] = self.lam
        fc[o + 2 * n: o + 3 * n] = self.x_o_fixed
        fc[o + 3 * n:] = self.Gamma.reshape(-1)
        all_knots = mrules.knots + crules.knots
        knots = np.zeros((M, max(len(k) for k in all_knots)))
        for J, kn in enumerate(all_knots):
            knots[J, : len(kn)] = kn
        ic = np.zeros((M, 4), dtype=np.int64)
        for J, inp in enumerate(inputs):
            ic[J] = (inp.terms, inp.control_points, inp.order, inp.order - 1)
        m = len(mrules.inputs)
        tidx = np.zeros((mrules.size + crules.size, max(m, 2)), dtype=np.int64)
        tidx[: mrules.size, :m] = mrules.term_index
        tidx[mrules.size:, :2] = crules.term_index
        width = max(mrules.size, crules.size, n + 1, m,
                    max(i.terms for i in inputs), max(i.order for i in inputs))
        self._fc = fc
        self._knots = knots
        self._ic = ic
        self._tidx = tidx
        self._ws = np.zeros((4 * M + 7, width))
        self._M = M
        # the control points are never replaced (rules.C are views into C_all)
        self._Cm = mrules.C_all
        self._Cc = crules.C_all
        self._compile()

    def _compile(self) -> None:
        """Compile (or load from the cache) the kernel now, on scratch copies of the state.

        Then the first sample of a run costs what every other one does, and a run's
        ``wall_s`` measures the loop, not numba.
        """
        n = self.n
        controller_step(np.zeros(n), np.zeros(n + 1), 1e-3, 0.0, self.model.P.copy(),
                        self._Cm.copy(), self.compensator.q.copy(), self._Cc.copy(),
                        np.zeros_like(self.diag), self._fc, self._knots, self._ic.copy(),
                        self._tidx, np.zeros_like(self._ws))

    def last_firing(self, x: np.ndarray | None = None) -> tuple[FiringView, FiringView]:
        """The last sample's memberships and firing strengths, read from the workspace.

        Rows of ``ws`` as :func:`controller_step` writes them: ``M + J`` memberships of
        input J, ``4 M`` the model's firing, ``4 M + 2`` the compensator's, ``4 M + 6``
        the model's input z.  ``x`` (the sample's state) gives the compensator's ||x||.
        """
        ws, M = self._ws, self._M
        mr, cr = self.model.rules, self.compensator.rules
        m = len(mr.inputs)
        z = np.clip(ws[4 * M + 6, :m], mr.lo, mr.hi)
        mu = [ws[M + j, : inp.terms].copy() for j, inp in enumerate(mr.inputs)]
        cmu = [ws[M + m + j, : inp.terms].copy() for j, inp in enumerate(cr.inputs)]
        x_norm = float(np.linalg.norm(x)) if x is not None else 0.0
        cz = np.clip(np.array([self.diag[self.layout["e_delta"]], x_norm]), cr.lo, cr.hi)
        return (FiringView(z, mu, ws[4 * M, : mr.size].copy()),
                FiringView(cz, cmu, ws[4 * M + 2, : cr.size].copy()))

    def step(self, x: np.ndarray, ref: np.ndarray, dt: float) -> float:
        """One controller sample (the numpy :meth:`AdaptiveFuzzyController.step`, compiled)."""
        u = controller_step(x, ref, dt, self.u_prev, self.model.P, self._Cm,
                            self.compensator.q, self._Cc, self.diag, self._fc, self._knots,
                            self._ic, self._tidx, self._ws)
        self.u_prev = u
        return u


def make_controller(cfg: ControllerConfig, backend: str = "auto") -> AdaptiveFuzzyController:
    """The controller for ``cfg`` on ``backend``: "numba", "numpy" or "auto".

    "auto" is the compiled controller when numba is importable and the numpy one
    otherwise (no error); "numba" raises ImportError without numba.
    """
    if backend not in BACKENDS:
        raise ValueError(f"unknown controller backend {backend!r}; expected one of {BACKENDS}")
    if backend == "numpy" or (backend == "auto" and not HAVE_NUMBA):
        return AdaptiveFuzzyController(cfg)
    return CompiledController(cfg)
