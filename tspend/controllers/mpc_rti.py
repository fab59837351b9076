"""The real-time schemes of ``mpc``: Gauss-Newton SQP with real-time iterations.

The optimal control problem is :mod:`.mpc`'s (same shooting map ``F``, weights, terminal
``P``, bounds).  Each sample takes the last plan shifted by one period as the
linearisation point ``z = (x_0, u_0, .., x_{N-1}, u_{N-1}, x_N)`` and solves the QP in the
step ``dz`` (Diehl, Bock and Schloeder, "A real-time iteration scheme for nonlinear
optimization in optimal feedback control", SIAM J. Control Optim. 43(5), 2005; Gros et
al., "From linear to nonlinear MPC: bridging the gap via the real-time iteration",
Int. J. Control 93(1), 2020):

    min  1/2 dz^T H dz + (H (z - z_r))^T dz                                  (R1)
    s.t. dx_0 = s(t) - x_0,
         dx_{k+1} = A_k dx_k + B_k du_k + F(x_k, u_k) - x_{k+1},             (R2)
         lo - z <= dz <= hi - z,
         G dz_k <= b_G - G z_k   (k < N: the task's rows, (M3) of :mod:`.mpc`)  (R3)

``A_k, B_k`` the Jacobians of ``F`` at ``(x_k, u_k)`` and ``H`` the cost's Hessian
(constant: the cost is quadratic, so this Gauss-Newton Hessian is exact for the cost and
drops only the dynamics' curvature).  The new plan is ``z + dz``; its first input is
applied.  ``rti`` takes one such step per sample; ``sqp`` repeats it (``sqp_iterations``)
until the step is below ``tolerance``.  A fixed point (``dz = 0``) satisfies the NLP's
KKT conditions whatever the Hessian, so iterated steps converge to IPOPT's solution of the
same problem (tests/test_mpc_rti.py).  A cold start (no plan yet) iterates up to
``sqp_iterations`` times in either scheme.

The QP keeps the stage structure (variables ordered by stage: a stage's state, then its
input and its slacks; (R2)'s rows of a stage followed by its (R3) rows, the order CasADi's
HPIPM interface reads as ``[gap_k, lincon_k]``), the form HPIPM exploits (a Riccati-based
interior point; Frison and Diehl, 2020); qrqp (CasADi's sparse active set, the default
without (R3): measured fastest here, docs/controllers.md), DAQP (dense active set) and
OSQP (ADMM) take it as a general sparse QP.  FATROP's QP interface is left out: in
CasADi 3.8.2 it prints its matrices on every call.  The linearisation (``F``, its Jacobian
over the horizon, (R1)'s gradient, the bounds, (R3)'s right-hand side) is one CasADi
function, generated as C and compiled with the system's C compiler (cached by the
source's hash under ``$TSPEND_CACHE_DIR/mpc``: the rows ``G, b_G``, the bounds and the
weights are constants in that source, so a different constraint set is another file), or
run in CasADi's virtual machine when
``compiled = false`` or no compiler is found.
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import tempfile
from pathlib import Path
from typing import Any, Callable, NamedTuple

import numpy as np

from tspend.runtime import cache

__all__ = ["QP_SOLVERS", "RealTimeSQP", "compiled_function"]

#: the QP solvers CasADi ships that the real-time schemes can use (the first is the
#: default: docs/controllers.md says why)
QP_SOLVERS = ("qrqp", "hpipm", "daqp", "osqp")

#: the lower end of an inequality row of (R3): none reached (rows are in the constraint's
#: unit, at most metres or radians per second)
_FAR = 1e10

#: each QP solver's options: quiet, errors raised (a failed QP is a failed sample)
_QP_OPTIONS: dict[str, dict[str, Any]] = {
    "hpipm": {"hpipm": {"mode": "speed", "iter_max": 100, "res_g_max": 1e-7, "res_b_max": 1e-7,
                        "res_d_max": 1e-7, "res_m_max": 1e-7}},
    "osqp": {"osqp": {"verbose": False, "eps_abs": 1e-6, "eps_rel": 1e-6, "polish": True,
                      "max_iter": 20000}, "warm_start_primal": True},
    "qrqp": {"print_iter": False, "print_header": False, "print_info": False},
    # daqp's default primal tolerance (1e-6) let (R3)'s rows end 2e-6 outside, which the
    # acceptance check below refuses
    "daqp": {"daqp": {"primal_tol": 1e-9}},
}


def cache_dir() -> Path | None:
    """Where compiled MPC functions are kept: ``$TSPEND_CACHE_DIR/mpc``, else
    ``$XDG_CACHE_HOME/tspend/mpc`` (``~/.cache``); None when it cannot be written."""
    from tspend.runtime.jit import writable_cache

    return writable_cache("mpc")


#: generated C above this size (bytes) is compiled -O1: the Furuta's 1.3 MB linearisation
#: takes gcc 31 s at -O2 and 16 s at -O1 and runs as fast (0.36 / 0.38 ms a call); the
#: double cart-pole's 0.6 MB runs 20 % faster at -O2 (0.175 / 0.21 ms) for 2.3 s more
O2_LIMIT_BYTES = 1_000_000


def optimisation(source_bytes: int) -> str:
    """gcc's optimisation level for a generated source of ``source_bytes``
    (:data:`O2_LIMIT_BYTES`)."""
    return "-O2" if source_bytes <= O2_LIMIT_BYTES else "-O1"


def compiled_function(fn: Any) -> Any:
    """``fn`` (a CasADi Function) generated as C, compiled with ``cc``/``gcc``
    (:func:`optimisation`: -O2, -O1 for a large source) and
    loaded back (:func:`casadi.external`); the shared object is cached by the hash of the
    C source, so a second process pays nothing.  ``fn`` itself when no compiler is found
    or the compilation fails (the same numbers, slower)."""
    import casadi

    loaded = compiled_casadi([fn], fn.name(), lambda so: casadi.external(fn.name(), str(so)))
    return fn if loaded is None else loaded


def compiled_casadi(fns: list, name: str, load: Callable[[Path], Any],
                    extra: bytes = b"") -> Any:
    """``load(the shared object)`` of the CasADi Functions ``fns`` generated as C into one
    source named ``name``, with ``extra`` C appended (:func:`compiled_library`; ``load``
    maps each back, e.g. by ``casadi.external(its name, the object)``); None without a
    compiler or when the compilation fails."""
    import casadi

    with tempfile.TemporaryDirectory(prefix="tspend-mpc-") as tmp:
        c_name = f"{name}.c"
        generator = casadi.CodeGenerator(c_name, {"with_header": False})
        for fn in fns:
            generator.add(fn)
        generator.generate(tmp + os.sep)
        return compiled_library(name, (Path(tmp) / c_name).read_bytes() + extra, load)


def compiled_library(name: str, source: bytes, load: Callable[[Path], Any]) -> Any:
    """``load(the shared object)`` of ``source`` (C) compiled with ``cc``/``gcc``, cached
    by the source's hash (a second process pays nothing) and checked before it is loaded
    (without a cache folder, loaded before its temporary folder goes); None without a
    compiler or when the compilation fails."""
    compiler = shutil.which("gcc") or shutil.which("cc")
    if compiler is None:
        return None
    with tempfile.TemporaryDirectory(prefix="tspend-mpc-") as tmp:
        c_path = Path(tmp) / f"{name}.c"
        c_path.write_bytes(source)
        key = hashlib.sha256(source).hexdigest()[:20]
        folder = cache_dir() or Path(tmp)
        so = folder / f"{name}_{key}.so"
        # checked before it is loaded (a damaged or foreign shared object could crash the
        # process): the sidecar's key, machine and checksum (tspend.runtime.cache)
        problem = cache.binary_problem(so, key)
        if problem is not None:
            if problem != "missing":
                cache.rebuilt("compiled MPC function", so, problem)
                cache.discard_binary(so)
            part = Path(tmp) / f"{so.name}.part"
            done = subprocess.run([compiler, optimisation(len(source)), "-fPIC", "-shared",
                                   "-o", str(part), str(c_path), "-lm"],
                                  capture_output=True, text=True)
            if done.returncode != 0:
                return None
            # built in the private folder, then moved: a concurrent process sees all of it
            # or none (a copy first when the cache is on another file system)
            staged = part if folder == Path(tmp) else _stage(part, folder)
            cache.write_binary(so, staged, key)
        return load(so)


def _stage(part: Path, folder: Path) -> Path:
    """``part`` copied into ``folder`` under a fresh hidden name (exclusively created)."""
    fd, name = tempfile.mkstemp(prefix=f".{part.name}.", suffix=".tmp", dir=folder)
    os.close(fd)
    shutil.copyfile(part, name)
    return Path(name)


class RealTimeSQP:
    """Gauss-Newton SQP steps (R1)-(R2) on the shooting OCP (module docstring).

    Parameters
    ----------
    F : casadi.Function
        ``F(s, u) -> s+``, the shooting map over one period.
    nx, N : int
        State size and horizon (intervals).
    stage_hessian, terminal_hessian : ndarray
        ``H`` of one stage (``(nx+1, nx+1)``: the state's, then the input's) and of the
        terminal state (``(nx, nx)``).
    z_lo, z_hi : ndarray
        Bounds on ``z`` (``+/-inf``: none; the first state is fixed by ``s(t)`` instead).
    solver : str
        One of :data:`QP_SOLVERS`.
    compiled : bool
        Generate and compile the linearisation with the C compiler.
    stage_rows, stage_bound : ndarray, optional
        ``G`` (``(r, nz)``) and ``b_G`` (``(r,)``) of (R3): ``G z_k <= b_G`` on every stage
        ``k < N`` (``z_k`` = its state, input and slacks).  None: no rows.
    stage_gradient : ndarray, optional
        A constant linear cost on each stage's ``z_k`` (``(nz,)``: the slacks' exact
        penalty).
    nz : int, optional
        A stage's size: ``nx + 1`` (state, input) plus its slacks.
    first_map : casadi.Function, optional
        The shooting map of stage 0 alone (another interval: the predictive safety
        filter's first interval is one control sample, the rest :data:`F`'s); needs N >= 2.
    terminal_constraint : casadi.Function, optional
        ``h(x_N)`` (``(t,)``): the last state must keep ``h <= 0`` (a terminal set),
        linearised as every other row, ``h + dh/dx dx_N <= 0``, after every other row
        (HPIPM's last stage).
    qp_options : dict, optional
        The QP solver's own options over :data:`_QP_OPTIONS` (``{"iter_max": 15}``).
    acceptance : float
        The largest constraint residual of a QP's answer taken as a step (else the QP failed).

    ``stage_hessian`` may also be ``(N, nz, nz)``: one per stage.
    """

    def __init__(self, F: Any, nx: int, N: int, stage_hessian: np.ndarray,
                 terminal_hessian: np.ndarray, z_lo: np.ndarray, z_hi: np.ndarray,
                 solver: str, compiled: bool, stage_rows: np.ndarray | None = None,
                 stage_bound: np.ndarray | None = None,
                 stage_gradient: np.ndarray | None = None, nz: int | None = None,
                 first_map: Any = None, terminal_constraint: Any = None,
                 qp_options: dict | None = None, acceptance: float = 1e-6) -> None:
        # the QP's data and its step are made by sqp_problem; this keeps them and the
        # persistent arrays CasADi's buffer evaluates on
        p = sqp_problem(F, nx, N, stage_hessian, terminal_hessian, z_lo, z_hi, solver,
                        compiled, stage_rows, stage_bound, stage_gradient, nz, first_map,
                        terminal_constraint, qp_options)
        self.nx, self.N, self.nz, self.nw, self.nr = nx, N, p.nz, p.nw, p.nr
        self.compiled, self.qp, self.step = p.compiled, p.qp, p.step
        self.solver = solver
        self.acceptance = acceptance
        #: the QP's data at a point, (z, s0, z_r) -> (g, A, lba, uba, lbx, ubx), and H
        self.linearisation, self.hessian = p.linearisation, p.hessian
        n_lam = p.nw + N * (nx + p.nr) + p.nt
        self._z, self._s0, self._zr = np.zeros(p.nw), np.zeros(nx), np.zeros(p.nw)
        self._lam = np.zeros(n_lam)
        self._out = np.zeros(p.nw + 2 + n_lam)
        self._buffer, self._evaluate = self.step.buffer()
        for i, array in enumerate((self._z, self._s0, self._zr, self._lam)):
            self._buffer.set_arg(i, memoryview(array))
        self._buffer.set_res(0, memoryview(self._out))

    def reset(self) -> None:
        self._lam[:] = 0.0

    def iterate(self, z: np.ndarray, s0: np.ndarray, zr: np.ndarray, iterations: int,
                tolerance: float, clock: Callable[[], float] | None = None,
                step_times: list[float] | None = None) -> tuple[np.ndarray, int]:
        """``(z, steps)`` after up to ``iterations`` steps from ``z`` (fewer when a step's
        largest entry is below ``tolerance``); raises RuntimeError when a QP's answer is
        not finite or violates its constraints by more than ``acceptance`` (a failed QP).
        Given both ``clock`` and ``step_times``, each step's time on that clock is
        appended to the list (a step's cost varies: the first from a cold start costs
        several times the later ones)."""
        nw, out = self.nw, self._out
        self._z[:] = z
        self._s0[:] = s0
        self._zr[:] = zr
        steps, timed = 0, clock is not None and step_times is not None
        while steps < iterations:
            started = clock() if timed else 0.0
            self._evaluate()
            steps += 1
            size, infeasibility = out[nw], out[nw + 1]
            if not (np.isfinite(size) and infeasibility <= self.acceptance) and np.any(self._lam):
                # the last solve's multipliers (not shifted with z) can start an active-set
                # solver on a wrong active set that it leaves slightly infeasible (seen
                # with qrqp and daqp once (R3)'s rows are active): once more from none
                self._lam[:] = 0.0
                self._evaluate()
                size, infeasibility = out[nw], out[nw + 1]
            if not (np.isfinite(size) and infeasibility <= self.acceptance):
                raise RuntimeError(f"the QP failed (step {size:g}, infeasibility "
                                   f"{infeasibility:g})")
            self._z[:] = out[:nw]
            self._lam[:] = out[nw + 2:]
            if not np.all(np.isfinite(self._lam)):
                # a solver's non-finite multipliers would poison the next warm start
                self._lam[:] = 0.0
            if timed:
                step_times.append(clock() - started)
            if size < tolerance:
                break
        return self._z.copy(), steps

    @staticmethod
    def shifted(z: np.ndarray, nz: int) -> np.ndarray:
        """``z`` one stage on: ``(x_1, u_1, .., x_N)`` then its last input and state again."""
        return np.concatenate([z[nz:], z[-nz:]])


class SQPProblem(NamedTuple):
    """What :func:`sqp_problem` makes once: the sizes, the QP's data as a function of the
    linearisation point, the QP solver and one SQP step through it."""

    nz: int
    nw: int
    nr: int
    nt: int
    #: (z, s0, z_r) -> (g, A, lba, uba, lbx, ubx), compiled when asked and possible
    linearisation: Any
    hessian: Any
    compiled: bool
    qp: Any
    #: (z, s0, z_r, lam) -> [z + dz, |dz|_inf, infeasibility, lam] in one vector
    step: Any


def sqp_problem(F: Any, nx: int, N: int, stage_hessian: np.ndarray,
                terminal_hessian: np.ndarray, z_lo: np.ndarray, z_hi: np.ndarray,
                solver: str, compiled: bool, stage_rows: np.ndarray | None = None,
                stage_bound: np.ndarray | None = None,
                stage_gradient: np.ndarray | None = None, nz: int | None = None,
                first_map: Any = None, terminal_constraint: Any = None,
                qp_options: dict | None = None) -> SQPProblem:
    """The SQP of :class:`RealTimeSQP` (its parameters), made once: the linearisation
    (:func:`_linearisation`, compiled with the C compiler when ``compiled``) and the QP
    solver with one step through it (:func:`_qp_step`)."""
    nz = nx + 1 if nz is None else nz
    G = np.zeros((0, nz)) if stage_rows is None else np.asarray(stage_rows, dtype=float)
    bG = np.zeros(0) if stage_bound is None else np.asarray(stage_bound, dtype=float)
    nt = 0 if terminal_constraint is None else terminal_constraint.size1_out(0)
    lin, H = _linearisation(F, nx, N, nz, stage_hessian, terminal_hessian, z_lo, z_hi, G, bG,
                            stage_gradient, first_map, terminal_constraint)
    a_sparsity = lin.sparsity_out(1)  # A's, as CasADi built it (before any compiling)
    is_compiled = False
    if compiled:
        fast = compiled_function(lin)
        is_compiled = fast is not lin
        lin = fast
    qp, step = _qp_step(lin, H, a_sparsity, solver, qp_options, nx, N, nz, G.shape[0], nt)
    return SQPProblem(nz, N * nz + nx, G.shape[0], nt, lin, H, is_compiled, qp, step)


def _dynamics(F: Any, first_map: Any, z: Any, nx: int, N: int, nz: int) -> tuple[Any, Any]:
    """``(defect, A)``: (R2)'s gaps ``F(x_k, u_k) - x_{k+1}`` at ``z`` and their Jacobian
    on ``z`` (each stage's on ``(x_k, u_k)``, nothing on its slacks)."""
    import casadi as ca

    nw = N * nz + nx
    s, u = ca.SX.sym("s", nx), ca.SX.sym("u")

    def jacobian_map(F: Any, name: str) -> Any:
        Fs = F(s, u)
        return ca.Function(name, [s, u], [Fs, ca.jacobian(Fs, ca.vertcat(s, u))])

    JF = jacobian_map(F, "JF")
    XU = ca.reshape(z[:N * nz], nz, N)
    if first_map is None:
        Fk, Jk = JF.map(N)(XU[:nx, :], XU[nx, :])
    else:
        F0, J0 = jacobian_map(first_map, "JF0")(XU[:nx, 0], XU[nx, 0])
        Fr, Jr = JF.map(N - 1)(XU[:nx, 1:], XU[nx, 1:])
        Fk, Jk = ca.horzcat(F0, Fr), ca.horzcat(J0, Jr)
    nxt = ca.reshape(ca.vertcat(z[nz:], ca.MX.zeros(nz - nx)), nz, N)[:nx, :]
    defect = ca.reshape(Fk - nxt, -1, 1)          # rows gap_0, gap_1, ..
    blocks = [ca.horzcat(b, ca.MX(nx, nz - nx - 1)) for b in ca.horzsplit(Jk, nx + 1)]
    shift = ca.DM(ca.Sparsity.triplet(N * nx, nw,
                                      [k * nx + i for k in range(N) for i in range(nx)],
                                      [(k + 1) * nz + i for k in range(N) for i in range(nx)]),
                  -1.0)
    return defect, ca.horzcat(ca.diagcat(*blocks), ca.MX(N * nx, nx)) + ca.MX(shift)


def _linearisation(F: Any, nx: int, N: int, nz: int, stage_hessian: np.ndarray,
                   terminal_hessian: np.ndarray, z_lo: np.ndarray, z_hi: np.ndarray,
                   G: np.ndarray, bG: np.ndarray, stage_gradient: np.ndarray | None,
                   first_map: Any, terminal_constraint: Any) -> tuple[Any, Any]:
    """``(lin, H)``: the QP's data at a point, ``(z, s0, z_r) -> (g, A, lba, uba, lbx,
    ubx)``, (R2)'s rows, then (R3)'s stage by stage, then the terminal set's; H sparse."""
    import casadi as ca

    nw, nr = N * nz + nx, G.shape[0]
    z, s0, zr = ca.MX.sym("z", nw), ca.MX.sym("s0", nx), ca.MX.sym("zr", nw)
    defect, A = _dynamics(F, first_map, z, nx, N, nz)
    stages = np.asarray(stage_hessian, dtype=float)
    stages = [stages] * N if stages.ndim == 2 else list(stages)
    H = ca.DM(ca.sparsify(ca.diagcat(*[ca.DM(h) for h in stages], ca.DM(terminal_hessian))))
    g = ca.mtimes(H, z - zr)
    if stage_gradient is not None:
        g = g + ca.DM(np.concatenate([np.tile(stage_gradient, N), np.zeros(nx)]))
    lo, hi = ca.DM(z_lo), ca.DM(z_hi)
    lbx = ca.vertcat(s0 - z[:nx], lo[nx:] - z[nx:])
    ubx = ca.vertcat(s0 - z[:nx], hi[nx:] - z[nx:])
    lba, uba = -defect, -defect
    if nr:
        # (R3) on every stage, then the rows in stage order: gap_k, then stage k's rows
        Gall = ca.DM(ca.sparsify(ca.horzcat(ca.diagcat(*([ca.DM(G)] * N)),
                                            ca.DM(N * nr, nx))))
        A = ca.vertcat(A, ca.MX(Gall))
        order = [i for k in range(N) for i in
                 list(range(k * nx, (k + 1) * nx)) + list(range(N * nx + k * nr,
                                                                N * nx + (k + 1) * nr))]
        A = A[order, :]
        rhs = ca.DM(np.tile(bG, N)) - ca.mtimes(Gall, z)
        # a far finite lower end, not -inf: with -inf qrqp (CasADi 3.8.2) reported
        # success on answers that broke an active row by millimetres
        lba = ca.vertcat(-defect, ca.DM.ones(N * nr) * -_FAR)[order]
        uba = ca.vertcat(-defect, rhs)[order]
    if terminal_constraint is not None:
        # the terminal set's rows on x_N, last (HPIPM's stage N)
        nt = terminal_constraint.size1_out(0)
        xN = ca.SX.sym("xN", nx)
        hN = terminal_constraint(xN)
        h_val, h_jac = ca.Function("Jh", [xN], [hN, ca.jacobian(hN, xN)])(z[N * nz:])
        A = ca.vertcat(A, ca.horzcat(ca.MX(nt, N * nz), h_jac))
        lba = ca.vertcat(lba, ca.DM.ones(nt) * -_FAR)
        uba = ca.vertcat(uba, -h_val)
    lin = ca.Function("tspend_mpc_lin", [z, s0, zr], [g, A, lba, uba, lbx, ubx],
                      ["z", "s0", "zr"], ["g", "a", "lba", "uba", "lbx", "ubx"])
    return lin, H


def _qp_step(lin: Any, H: Any, a_sparsity: Any, solver: str, qp_options: dict | None,
             nx: int, N: int, nz: int, nr: int, nt: int) -> tuple[Any, Any]:
    """``(qp, step)``: the QP solver ``solver`` on the sparsity of ``lin``'s data and one
    SQP step through it, with how far its answer is from feasible."""
    import casadi as ca

    nw = N * nz + nx
    opts = dict(_QP_OPTIONS[solver])
    if qp_options:
        # the solver's own options, over the defaults (mpsc: a proposal it certifies)
        opts[solver] = {**opts.get(solver, {}), **qp_options}
    # a failed QP is found by its result's infeasibility (below), not by an exception
    # (CasADi prints the QP's data with it)
    opts["error_on_fail"] = False
    if solver == "hpipm":
        opts.update(N=N, nx=[nx] * (N + 1), nu=[nz - nx] * N + [0], ng=[nr] * N + [nt])
    zs, s0s, zrs = ca.MX.sym("z", nw), ca.MX.sym("s0", nx), ca.MX.sym("zr", nw)
    gq, Aq, la, ua, lq, uq = lin(zs, s0s, zrs)
    qp = ca.conic("tspend_mpc_qp", solver, {"h": H.sparsity(), "a": a_sparsity}, opts)
    lam = ca.MX.sym("lam", nw + N * (nx + nr) + nt)
    sol = qp(h=H, g=gq, a=Aq, lba=la, uba=ua, lbx=lq, ubx=uq,
             lam_x0=lam[:nw], lam_a0=lam[nw:])
    dz = sol["x"]
    # how far the QP's answer is from feasible: (R2)'s residual, (R3)'s and the bounds'
    # excess (an inequality row's lower end is -inf)
    Adz = ca.mtimes(Aq, dz)
    infeasibility = ca.mmax(ca.vertcat(la - Adz, Adz - ua, lq - dz, dz - uq))
    # one step in one vector, evaluated through CasADi's buffer interface on persistent
    # arrays (a Python call with conversions costs 0.1 ms, the buffer's a microsecond)
    step = ca.Function("tspend_mpc_step", [zs, s0s, zrs, lam],
                       [ca.vertcat(zs + dz, ca.norm_inf(dz), infeasibility,
                                   sol["lam_x"], sol["lam_a"])])
    return qp, step
