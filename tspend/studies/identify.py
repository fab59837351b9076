"""Identify a machine's physical parameters from a recorded run (``tspend identify``).

Method: *multiple shooting* of the domain's own equations, solved as a nonlinear least
squares problem by :func:`scipy.optimize.least_squares` (trust-region reflective, bounds
keep masses positive) with exact Jacobians from CasADi.

* The training part of the record (the first ``1 - validation`` of it) is cut into
  segments of ``segment_s`` seconds.  Each segment is simulated from its own initial state
  (a decision variable: the velocities need not be measured, and the noisy first sample is
  not trusted) with the recorded input held over each sample (zero-order hold, as MuJoCo
  holds ``ctrl``) by RK4 at the model's own timestep.  The residuals are the measured
  positions (and velocities if asked) minus the simulated ones, each channel divided by
  its noise level.  Short segments keep an unstable machine's simulation from diverging,
  so the error surface stays smooth; the unknowns are ``p`` and the segments' states.
* Why least_squares rather than IPOPT: the problem is a plain sum of squares with box
  bounds and no other constraint; a Gauss-Newton-type solver uses that structure, its
  Jacobian at the solution is what the uncertainty needs, and it has no tuning.  CasADi
  builds the simulation and its sensitivities exactly (forward mode over the segment's
  ``mapaccum``), so no finite differences enter.
* Uncertainty: the Gauss-Newton covariance ``(J^T W J)^-1`` with ``W`` each channel's
  inverse noise variance estimated from that channel's own residuals at the solution
  (``RSS_c / (N_c - k_c)``), taken for the parameters after eliminating the segments'
  states (Schur complement); 95 % intervals are +/- 1.96 standard deviations.  Valid when
  the model structure is right and the noise white: then the residuals are the noise.
* Identifiability, before any fit: the sensitivity Jacobian at the nominal values, with
  the segments' states projected out, its columns as log-sensitivities (``p dr/dp``) and
  normalised.  A (near) zero singular value means a combination of the parameters the
  motion cannot see; the combinations it can fix span the other right singular vectors,
  reported as products of powers (``m/gear``).  A zero column means the record never
  excites that parameter.
* Validation: the last ``validation`` share of the record, in windows of ``segment_s``:
  each window's initial state is estimated from its first ``head_s`` with the parameters
  fixed, then the model predicts the rest of the window freely; the RMS of that prediction
  error is reported for the fitted and the nominal parameters.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from tspend.runtime.errors import ScenarioError, TspendError
from tspend.studies.identify_model import OFFSET, ParametricModel

__all__ = ["Record", "Fit", "FitFailed", "read_record", "column", "check_names",
           "identifiability", "fit", "RANK_TOL"]

#: a singular value of the normalised log-sensitivity matrix below RANK_TOL times the
#: largest marks a combination of parameters the record cannot fix
RANK_TOL = 1e-6
#: the fewest samples a record must have
MIN_SAMPLES = 200


class FitFailed(TspendError):
    """The fit did not converge (``tspend identify`` exits 3 and writes nothing)."""

    exit_status = 3


@dataclass(frozen=True)
class Record:
    """A recorded run as the fit reads it: uniform time ``t`` (s), positions ``y`` (N, dof)
    in the model's coordinates, velocities ``v`` (N, dof) or None, input ``u`` and
    disturbance ``d`` (N,), and the columns they came from."""

    t: np.ndarray
    y: np.ndarray
    v: np.ndarray | None
    u: np.ndarray
    d: np.ndarray
    columns: dict[str, str]

    @property
    def dt(self) -> float:
        return float(self.t[1] - self.t[0])


def column(frame, candidates: Sequence[str], what: str, required: bool = True) -> str | None:
    """The one mapping from a quantity to its column: the first of ``candidates`` the table
    has (an export names a joint by the domain's symbol, ``theta_rad``, or by the joint's
    name, ``hinge_rad``: both are accepted)."""
    for c in candidates:
        if c and c in frame.columns:
            return c
    if required:
        raise ScenarioError(f"DATA: no {what} column (looked for {', '.join(c for c in candidates if c)}; "
                            f"the table has {', '.join(map(str, list(frame.columns)[:12]))}"
                            f"{' ...' if len(frame.columns) > 12 else ''}); map it with an option")
    return None


def _read_table(path: Path):
    import pandas as pd

    if not path.is_file():
        raise ScenarioError(f"DATA {path}: no such file")
    try:
        if path.suffix == ".parquet":
            return pd.read_parquet(path)
        if path.suffix == ".csv":
            return pd.read_csv(path, comment="#")
    except Exception as exc:  # noqa: BLE001 - any reader failure is bad input
        raise ScenarioError(f"DATA {path}: cannot read it: {type(exc).__name__}: "
                            f"{str(exc).splitlines()[0] if str(exc) else ''}") from None
    raise ScenarioError(f"DATA {path}: format from the suffix: .csv or .parquet, not "
                        f"'{path.suffix}'")


def read_record(path: str | Path, model: ParametricModel, *, time: str | None = None,
                positions: Sequence[str] | None = None, velocities: Sequence[str] | None = None,
                input: str | None = None, use_velocities: bool = False) -> Record:
    """Read and check a table: one line (ScenarioError) naming what is wrong with it."""
    frame = _read_table(Path(path))
    dof = model.dof
    if positions is not None and len(positions) != dof:
        raise ScenarioError(f"--positions: {dof} columns expected ({', '.join(model.state_names[:dof])}), "
                            f"got {len(positions)}")
    if velocities is not None and len(velocities) != dof:
        raise ScenarioError(f"--velocities: {dof} columns expected, got {len(velocities)}")
    tc = column(frame, [time] if time else ["t_s", "t", "time"], "time")
    pcs = [column(frame, [positions[i]] if positions else model.position_columns[i],
                  f"position of '{model.state_names[i]}'") for i in range(dof)]
    uc = column(frame, [input] if input else model.input_columns, "input")
    dc = None if input else column(frame, model.disturbance_columns, "disturbance", required=False)
    vcs = None
    if use_velocities:
        vcs = [column(frame, [velocities[i]] if velocities else model.velocity_columns[i],
                      f"velocity of '{model.state_names[i]}'") for i in range(dof)]
    used = [tc, *pcs, uc, *(vcs or []), *([dc] if dc else [])]
    for c in used:
        values = frame[c].to_numpy()
        if not np.issubdtype(values.dtype, np.number):
            raise ScenarioError(f"DATA: column '{c}' is not numeric")
        bad = ~np.isfinite(values.astype(float))
        if bad.any():
            raise ScenarioError(f"DATA: column '{c}' has {int(bad.sum())} NaN or infinite "
                                f"value(s), the first at row {int(np.argmax(bad))}")
    t = frame[tc].to_numpy(float)
    if t.size < MIN_SAMPLES:
        raise ScenarioError(f"DATA: too short: {t.size} samples, at least {MIN_SAMPLES} needed")
    dt = np.diff(t)
    if np.any(dt <= 0.0):
        i = int(np.argmax(dt <= 0.0))
        raise ScenarioError(f"DATA: time '{tc}' is not increasing at row {i + 1} "
                            f"({t[i]:g} s then {t[i + 1]:g} s)")
    if np.max(np.abs(dt - dt.mean())) > 1e-3 * dt.mean():
        raise ScenarioError(f"DATA: time '{tc}' is not uniformly sampled (steps {dt.min():g} to "
                            f"{dt.max():g} s); resample it first")
    signs = np.asarray(model.position_signs, dtype=float)
    y = np.column_stack([frame[c].to_numpy(float) for c in pcs]) * signs
    v = (np.column_stack([frame[c].to_numpy(float) for c in vcs]) * signs) if vcs else None
    u = frame[uc].to_numpy(float)
    d = frame[dc].to_numpy(float) if dc else np.zeros_like(u)
    cols = {"time": tc, "input": uc, **{f"position:{model.state_names[i]}": pcs[i] for i in range(dof)}}
    if vcs:
        cols.update({f"velocity:{model.state_names[i]}": vcs[i] for i in range(dof)})
    if dc:
        cols["disturbance"] = dc
    return Record(t=t, y=y, v=v, u=u, d=d, columns=cols)


def check_names(model: ParametricModel, names: Sequence[str]) -> tuple[str, ...]:
    names = tuple(n.strip() for n in names if n.strip())
    if not names:
        raise ScenarioError("--params: name at least one parameter; allowed: " + ", ".join(model.names))
    for n in names:
        if n in model.refused:
            raise ScenarioError(f"--params {n}: not offered: {model.refused[n]}")
    unknown = [n for n in names if n not in model.names]
    if unknown:
        raise ScenarioError(f"--params: unknown for the {model.domain} ({model.path}): "
                            f"{', '.join(unknown)}; allowed: {', '.join(model.names)}")
    if len(set(names)) != len(names):
        raise ScenarioError(f"--params: a name is given twice ({', '.join(names)})")
    return names


def _scale(model: ParametricModel, name: str) -> float:
    """The unit the solver sees a parameter in: its nominal value (or 1 if that is 0)."""
    v = abs(model.nominal[name])
    return v if v > 0.0 else 1.0


class _Problem:
    """The segmented simulation of one record: CasADi functions and the data cut to fit."""

    def __init__(self, model: ParametricModel, rec: Record, names: tuple[str, ...],
                 starts: Sequence[int], length: int, use_velocities: bool) -> None:
        self.model, self.rec, self.names = model, rec, names
        self.starts, self.K = list(starts), int(length)
        n, dof = len(model.state_names), model.dof
        self.n, self.dof, self.k = n, dof, len(names)
        self.meas_rows = list(range(dof)) + (list(range(dof, n)) if use_velocities else [])
        substeps = max(1, int(round(rec.dt / model.timestep))) if model.timestep > 0 else 1
        h = rec.dt / substeps
        self.scales = np.array([_scale(model, nm) for nm in names])
        key = (names, tuple(sorted(model.fixed.items())), self.K, tuple(self.meas_rows),
               substeps, h, model.jit)
        if key not in model.compiled:
            model.compiled[key] = self._build(substeps, h)
        seg, self.traj = model.compiled[key]
        self.seg = seg.map(len(self.starts), "serial") if self.starts else seg

    def _build(self, substeps: int, h: float):
        """The segment's simulation and its Jacobian (CasADi), and its full trajectory."""
        import casadi

        model, names, n, dof = self.model, self.names, self.n, self.dof
        s = casadi.SX.sym("s", n)
        u = casadi.SX.sym("u")
        d = casadi.SX.sym("d")
        theta = casadi.SX.sym("theta", self.k)   # scaled: p = theta * scale
        p = {nm: theta[i] * self.scales[i] for i, nm in enumerate(names)}
        x = s
        for _ in range(substeps):
            k1 = model.rhs(x, u, d, p)
            k2 = model.rhs(x + h / 2 * k1, u, d, p)
            k3 = model.rhs(x + h / 2 * k2, u, d, p)
            k4 = model.rhs(x + h * k3, u, d, p)
            x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
        step = casadi.Function("step", [s, u, d, theta], [x])
        sim = step.mapaccum("sim", self.K - 1)
        s0 = casadi.MX.sym("s0", n)
        th = casadi.MX.sym("th", self.k)
        U = casadi.MX.sym("U", 1, self.K - 1)
        D = casadi.MX.sym("D", 1, self.K - 1)
        traj = casadi.horzcat(s0, sim(s0, U, D, th))                 # n x K
        # what the sensors read: each position plus its sensor offset (0 unless fitted/fixed)
        off = casadi.Function("off", [theta], [casadi.vertcat(
            *[casadi.SX(o) for o in model.offsets(p)], casadi.SX.zeros(n - dof))])(th)
        traj_meas = traj + casadi.repmat(off, 1, self.K)
        out = casadi.vec(traj_meas[self.meas_rows, :].T)             # channel-major
        z = casadi.vertcat(s0, th)
        seg = casadi.Function("seg", [s0, th, U, D], [out, casadi.jacobian(out, z)])
        if model.jit:
            seg = _compiled(seg)
        return seg, casadi.Function("traj", [s0, th, U, D], [traj])

    def data(self, arr: np.ndarray) -> np.ndarray:
        """(K - 1) samples of ``arr`` for each segment, side by side."""
        return np.concatenate([arr[a:a + self.K - 1] for a in self.starts])[None, :]

    def measured(self) -> np.ndarray:
        """(segments, channels, K) measured channels."""
        rec = self.rec
        full = rec.y if rec.v is None or len(self.meas_rows) == self.dof else np.hstack([rec.y, rec.v])
        return np.stack([full[a:a + self.K].T for a in self.starts])

    def simulate(self, S0: np.ndarray, theta: np.ndarray):
        """Simulated channels (segments, channels, K) and their Jacobian blocks."""
        nseg = len(self.starts)
        out, jac = self.seg(S0.T, np.tile(theta[:, None], (1, nseg)),
                            self.data(self.rec.u), self.data(self.rec.d))
        out = np.asarray(out).T.reshape(nseg, len(self.meas_rows), self.K)
        jac = np.asarray(jac).reshape(len(self.meas_rows) * self.K, nseg, self.n + self.k)
        return out, np.transpose(jac, (1, 0, 2))


def _compiled(fn):
    """``fn`` compiled to C by the system's ``cc`` and loaded (``casadi.external``), kept in
    the derivation cache (``$TSPEND_CACHE_DIR/articulated/identify``) under a hash of its
    generated source, so a second process with the same machine, parameters and segment
    length loads it without compiling; ``fn`` itself when there is no compiler or cache."""
    import hashlib
    import os
    import shutil
    import subprocess
    import tempfile

    import casadi

    from tspend.plants.articulated.derive import cache_dir
    from tspend.runtime import cache

    cc = shutil.which("cc")
    root = cache_dir()
    if cc is None or root is None:
        return fn
    folder = root / "identify"
    folder.mkdir(exist_ok=True)
    with tempfile.TemporaryDirectory(dir=folder) as tmp:
        cg = casadi.CodeGenerator("seg.c", {"with_header": False})
        cg.add(fn)
        cg.generate(tmp + os.sep)
        src = Path(tmp, "seg.c").read_bytes()
        key = hashlib.sha256(src).hexdigest()[:20]
        lib = folder / f"seg_{key}.so"
        # checked before it is loaded (garbage or another build could crash the process):
        # its sidecar's key, machine and checksum (tspend.runtime.cache), rebuilt if wrong
        problem = cache.binary_problem(lib, key)
        if problem is not None:
            if problem != "missing":
                cache.rebuilt("compiled identification segment", lib, problem)
                cache.discard_binary(lib)
            out = Path(tmp, "seg.so")
            r = subprocess.run([cc, "-O1", "-fPIC", "-shared", str(Path(tmp, "seg.c")), "-o",
                                str(out), "-lm"], capture_output=True, text=True)
            if r.returncode != 0:
                return fn                   # CasADi's virtual machine, as without a compiler
            cache.write_binary(lib, out, key)   # atomic: a concurrent process sees all or none
    return casadi.external(fn.name(), str(lib))


def _initial_states(rec: Record, starts: Sequence[int], n: int, dof: int) -> np.ndarray:
    """Positions at each start, velocities by a local quadratic fit (Savitzky-Golay)."""
    from scipy.signal import savgol_filter

    win = max(5, int(round(0.05 / rec.dt)) | 1)
    win = min(win, (rec.t.size - 1) | 1 if rec.t.size % 2 == 0 else rec.t.size)
    vel = rec.v if rec.v is not None else savgol_filter(rec.y, win, 2, deriv=1, delta=rec.dt, axis=0)
    pos = savgol_filter(rec.y, win, 2, axis=0)
    return np.array([np.concatenate([pos[a], vel[a]]) for a in starts])


@dataclass
class Fit:
    """What a fit found."""

    names: tuple[str, ...]
    values: dict[str, float]
    nominal: dict[str, float]
    std: dict[str, float]
    correlation: np.ndarray
    noise_std: dict[str, float]
    rms_fit: dict[str, float]
    rms_validation: dict[str, float]
    rms_validation_nominal: dict[str, float]
    iterations: int
    segments: int
    segment_s: float
    train_s: float
    validation_s: float
    status: str
    #: for the figure: (t, measured, predicted) of the validation windows, per channel
    validation_trace: dict[str, Any] = field(default_factory=dict, repr=False)
    #: "curvature" (Gauss-Newton) or "bootstrap" (segments resampled)
    uncertainty: str = "curvature"
    #: the bootstrap's estimates (replicates x parameters), or None
    replicates: np.ndarray | None = field(default=None, repr=False)
    #: the curvature's std, kept beside the bootstrap's for comparison
    std_curvature: dict[str, float] = field(default_factory=dict)

    def interval(self, name: str, z: float = 1.959963984540054) -> tuple[float, float]:
        """The 95 % interval: +/- z std (curvature), or the bootstrap's 2.5 and 97.5 %
        percentiles."""
        if self.uncertainty == "bootstrap" and self.replicates is not None:
            col = self.replicates[:, self.names.index(name)]
            lo, hi = np.percentile(col, [2.5, 97.5])
            return float(lo), float(hi)
        v, s = self.values[name], self.std[name]
        return v - z * s, v + z * s

    def to_json(self) -> dict[str, Any]:
        return {"parameters": {n: {"value": self.values[n], "std": self.std[n],
                                   "ci95": list(self.interval(n)), "nominal": self.nominal[n]}
                               for n in self.names},
                "correlation": self.correlation.round(6).tolist(),
                "noise_std": self.noise_std, "rms_fit": self.rms_fit,
                "rms_validation": self.rms_validation,
                "rms_validation_nominal": self.rms_validation_nominal,
                "iterations": self.iterations, "segments": self.segments,
                "segment_s": self.segment_s, "train_s": self.train_s,
                "validation_s": self.validation_s, "status": self.status,
                "uncertainty": self.uncertainty,
                "std_curvature": self.std_curvature,
                "bootstrap_replicates": (0 if self.replicates is None else
                                         int(self.replicates.shape[0]))}


def auto_segment(model: ParametricModel, dt: float) -> float:
    """The shooting segments' default length, s: ``2 / lambda`` for the fastest unstable
    eigenvalue ``lambda`` of the nominal machine at its zero state (upright; a
    simulation error then grows at most ~e^2 over a segment, which keeps the least-squares
    problem well conditioned), within [50 dt, 2 s]; 2 s for a stable machine."""
    import casadi

    s = casadi.SX.sym("s", len(model.state_names))
    A = casadi.Function("A", [s], [casadi.jacobian(model.rhs(s, 0.0, 0.0, {}), s)])
    lam = float(np.max(np.linalg.eigvals(np.asarray(A(np.zeros(len(model.state_names))))).real))
    seg = 2.0 / lam if lam > 0 else 2.0
    return float(min(max(seg, 50 * dt), 2.0))


def _segments(first: int, last: int, K: int) -> list[int]:
    return list(range(first, last - K + 1, K - 1))


def _channel_names(model: ParametricModel, meas_rows: Sequence[int]) -> list[str]:
    return [model.state_names[r] for r in meas_rows]


def identifiability(model: ParametricModel, rec: Record, names: tuple[str, ...], *,
                    segment_s: float | None = None, validation: float = 0.25) -> list[str]:
    """Refuse a set of parameters the record cannot fix (ScenarioError naming what it can
    fix); return nothing when the set is identifiable.  From the sensitivity Jacobian at
    the nominal values (the module docstring)."""
    N = rec.t.size
    segment_s = segment_s or auto_segment(model, rec.dt)
    K = max(3, int(round(segment_s / rec.dt)) + 1)
    last = int(N * (1.0 - validation))
    starts = _segments(0, last, K)
    if not starts:
        raise ScenarioError(f"DATA: too short for one {segment_s:g} s segment before the "
                            f"validation part ({rec.t[-1] - rec.t[0]:g} s recorded)")
    prob = _Problem(model, rec, names, starts[:: max(1, len(starts) // 8)], K, False)
    S0 = _initial_states(rec, prob.starts, prob.n, prob.dof)
    theta = np.array([model.nominal[nm] for nm in names]) / prob.scales
    _, jac = prob.simulate(S0, theta)
    rows = []
    for j in range(len(prob.starts)):
        Js, Jp = jac[j][:, :prob.n], jac[j][:, prob.n:]
        Q, _ = np.linalg.qr(Js)
        rows.append(Jp - Q @ (Q.T @ Jp))         # the states' part projected out
    Jp = np.vstack(rows)
    # log-sensitivities: d r / d log p = p dr/dp (p = theta * scale, theta = p/scale)
    logs = np.array([model.nominal[nm] != 0.0 for nm in names])
    Jl = Jp * np.where(logs, theta, 1.0)
    norms = np.linalg.norm(Jl, axis=0)
    if norms.max() == 0.0:
        raise ScenarioError(f"DATA: the record excites none of {', '.join(names)} (the motion "
                            f"does not depend on them: is the input '{rec.columns['input']}' zero?)")
    dead = [nm for nm, c in zip(names, norms) if c <= 1e-9 * norms.max()]
    if dead and all(nm.endswith(OFFSET) for nm in dead):
        raise ScenarioError(f"--params {', '.join(dead)}: the recorded motion does not depend "
                            f"on a constant offset of {'this joint' if len(dead) == 1 else 'these joints'} "
                            f"(the equations do not change when it moves, so each segment's "
                            f"start absorbs the offset): not identifiable")
    if dead:
        raise ScenarioError(f"DATA: the input '{rec.columns['input']}' never excites "
                            f"{', '.join(dead)}: the recorded motion does not depend on "
                            f"{'it' if len(dead) == 1 else 'them'}")
    Jn = Jl / norms
    _, sv, Vt = np.linalg.svd(Jn, full_matrices=False)
    null = sv < RANK_TOL * sv[0]
    if not null.any():
        return []
    from scipy.linalg import null_space

    free = Vt[null] / norms                  # back from normalised to log (or raw) units
    free /= np.linalg.norm(free, axis=1, keepdims=True)
    # the same directions in raw units (d p = p d log p): the fixable combinations read as
    # products of powers (ratios: m/gear) or as sums (arm_damping + back_emf), whichever has
    # the simpler coefficients
    p0 = np.array([model.nominal[nm] if lg else 1.0 for nm, lg in zip(names, logs)])
    raw = free * p0
    raw /= np.linalg.norm(raw, axis=1, keepdims=True)
    as_log = _rref(null_space(free).T)
    as_raw = _rref(null_space(raw).T)
    if _roughness(as_raw) < _roughness(as_log) or not np.all(logs):
        combos = _combinations(as_raw, names, np.zeros_like(logs))
    else:
        combos = _combinations(as_log, names, logs)
    raise ScenarioError(
        f"--params {','.join(names)}: not identifiable from motion: the data fix only "
        f"{len(combos)} combination{'s' if len(combos) != 1 else ''} of them: "
        f"{', '.join(combos)}; "
        f"give one of them its known value (leave it out of --params)")


def _rref(A: np.ndarray) -> np.ndarray:
    A = A.copy()
    r = 0
    for c in range(A.shape[1]):
        if r >= A.shape[0]:
            break
        piv = r + int(np.argmax(np.abs(A[r:, c])))
        if abs(A[piv, c]) < 1e-8:
            continue
        A[[r, piv]] = A[[piv, r]]
        A[r] /= A[r, c]
        for i in range(A.shape[0]):
            if i != r:
                A[i] -= A[i, c] * A[r]
        r += 1
    return A[:r]


def _roughness(rows: np.ndarray) -> float:
    """How far a basis's coefficients are from small integers (0 for 1, -1, 2 ...)."""
    return float(np.sum(np.abs(rows - np.round(rows))))


def _power(e: float) -> str:
    e = round(e, 2)
    return "" if e == 1 else (f"^{e:g}")


def _combinations(basis: np.ndarray, names: Sequence[str], logs: np.ndarray) -> list[str]:
    """Each row of the basis in reduced row echelon form, as a product of powers (log-scaled
    parameters) or a weighted sum (the others)."""
    out = []
    for row in basis:
        row = np.where(np.abs(row - np.round(row)) < 1e-6, np.round(row), row)
        if np.all(logs | (row == 0)):
            num = [f"{n}{_power(e)}" for n, e in zip(names, row) if e > 0]
            den = [f"{n}{_power(-e)}" for n, e in zip(names, row) if e < 0]
            text = " ".join(num) or "1"
            if den:
                text += "/" + (den[0] if len(den) == 1 else "(" + " ".join(den) + ")")
            out.append(text)
        else:
            terms = [(f"{'' if abs(e) == 1 else f'{abs(e):.3g} '}{n}", e) for n, e in zip(names, row) if e != 0]
            out.append("".join(("" if i == 0 and e > 0 else (" - " if e < 0 else " + ")) + t
                               for i, (t, e) in enumerate(terms)).strip())
    return out


def _direction(v: np.ndarray, names: Sequence[str], logs: np.ndarray) -> str:
    v = v / v[np.argmax(np.abs(v))]
    return "scaling " + " ".join(f"{n}{_power(e)}" for n, e in zip(names, v) if abs(e) > 1e-6) \
        if np.all(logs) else ", ".join(f"{e:.3g} d{n}" for n, e in zip(names, v) if abs(e) > 1e-6)


def _solve(prob: _Problem, S0: np.ndarray, theta0: np.ndarray, sigma: np.ndarray,
           fit_theta: bool, max_nfev: int):
    """least_squares over (segments' states, theta): returns (S0, theta, result)."""
    from scipy.optimize import least_squares

    nseg, n, k = len(prob.starts), prob.n, prob.k
    meas = prob.measured()
    w = (1.0 / sigma)[None, :, None]
    nvar = nseg * n + (k if fit_theta else 0)
    C, K = meas.shape[1], meas.shape[2]

    def unpack(z):
        S = z[: nseg * n].reshape(nseg, n)
        th = z[nseg * n:] if fit_theta else theta0
        return S, th

    cache: dict[bytes, Any] = {}

    def run(z):
        key = z.tobytes()
        if key not in cache:
            cache.clear()
            S, th = unpack(z)
            cache[key] = prob.simulate(S, th)
        return cache[key]

    def res(z):
        out, _ = run(z)
        return ((out - meas) * w).ravel()

    def jac(z):
        _, J = run(z)
        M = np.zeros((nseg * C * K, nvar))
        wr = np.repeat(1.0 / sigma, K)[:, None]
        for j in range(nseg):
            rows = slice(j * C * K, (j + 1) * C * K)
            M[rows, j * n:(j + 1) * n] = J[j][:, :n] * wr
            if fit_theta:
                M[rows, nseg * n:] = J[j][:, n:] * wr
        return M

    z0 = np.concatenate([S0.ravel(), theta0 if fit_theta else []])
    lo = np.full(nvar, -np.inf)
    if fit_theta:
        lo[nseg * n:] = np.where(np.array([prob.model.nominal[nm] > 0 for nm in prob.names]),
                                 1e-6, -np.inf)
    r = least_squares(res, z0, jac=jac, bounds=(lo, np.inf), method="trf", x_scale="jac",
                      xtol=1e-12, ftol=1e-12, gtol=1e-10, max_nfev=max_nfev)
    S, th = unpack(r.x)
    return S, th, r


def _validate(model: ParametricModel, rec: Record, names, theta: np.ndarray, scales,
              first: int, K: int, head: int):
    """Free-run prediction RMS per position channel over the validation windows (each
    window's state estimated from its first ``head`` samples, parameters fixed)."""
    starts = _segments(first, rec.t.size, K)
    if not starts:
        return {}, {}
    head_prob = _Problem(model, rec, names, starts, head, False)
    S0 = _initial_states(rec, starts, head_prob.n, head_prob.dof)
    sigma = np.ones(head_prob.dof)
    S, _, _ = _solve(head_prob, S0, theta, sigma, False, 50)
    pred = _Problem(model, rec, names, starts, K, False)
    out, _ = pred.simulate(S, theta)
    meas = pred.measured()
    err = (out - meas)[:, :, head:]
    rms = {model.state_names[c]: float(np.sqrt(np.mean(err[:, c] ** 2))) for c in range(pred.dof)}
    trace = {"t": np.stack([rec.t[a:a + K] for a in starts]), "measured": meas, "predicted": out,
             "head": head}
    return rms, trace


def fit(model: ParametricModel, rec: Record, names: tuple[str, ...], *,
        segment_s: float | None = None, validation: float = 0.25, head_share: float = 0.2,
        use_velocities: bool = False, max_nfev: int = 100, bootstrap: int = 0,
        rng: np.random.Generator | None = None) -> Fit:
    """Fit ``names`` to ``rec`` (see the module docstring).  Raises FitFailed when the
    solver stops without converging or the curvature is singular.

    ``bootstrap`` > 0: the uncertainty from that many refits on the training segments
    resampled with replacement (``rng`` draws them; each refit starts from the fit), a
    block bootstrap that keeps each segment's own noise, coloured or not: ``std`` is the
    replicates' spread and the interval their 2.5-97.5 % percentiles."""
    N = rec.t.size
    segment_s = segment_s or auto_segment(model, rec.dt)
    K = max(3, int(round(segment_s / rec.dt)) + 1)
    last = int(N * (1.0 - validation))
    starts = _segments(0, last, K)
    if not starts:
        raise ScenarioError(f"DATA: too short for one {segment_s:g} s segment")
    prob = _Problem(model, rec, names, starts, K, use_velocities and rec.v is not None)
    S0 = _initial_states(rec, starts, prob.n, prob.dof)
    theta = np.array([model.nominal[nm] for nm in names]) / prob.scales
    meas = prob.measured()
    # first pass: channels weighted by their spread; then by their own residual noise
    sigma = np.maximum(meas.std(axis=(0, 2)), 1e-12)
    total = 0
    for _ in range(2):
        S0, theta, r = _solve(prob, S0, theta, sigma, True, max_nfev)
        total += r.nfev
        if r.status <= 0:
            raise FitFailed(f"the fit did not converge ({r.message.strip()}) after {total} "
                            f"evaluations")
        out, _ = prob.simulate(S0, theta)
        resid = out - meas
        dof_c = resid.shape[0] * resid.shape[2] - (len(theta) + prob.n * len(starts)) / resid.shape[1]
        sigma = np.maximum(np.sqrt((resid ** 2).sum(axis=(0, 2)) / dof_c), 1e-15)
    # Gauss-Newton covariance with the final weights
    S0, theta, r = _solve(prob, S0, theta, sigma, True, max_nfev)
    total += r.nfev
    if r.status <= 0:
        raise FitFailed(f"the fit did not converge ({r.message.strip()}) after {total} evaluations")
    J = r.jac
    JTJ = J.T @ J
    try:
        cov_all = np.linalg.inv(JTJ)
    except np.linalg.LinAlgError:
        raise FitFailed("the fit's curvature is singular: the parameters are not determined") from None
    k = len(names)
    cov = cov_all[-k:, -k:] * np.outer(prob.scales, prob.scales)
    if not np.all(np.isfinite(cov)) or np.any(np.diag(cov) < 0):
        raise FitFailed("the fit's curvature is not positive definite")
    std = np.sqrt(np.diag(cov))
    corr = cov / np.outer(std, std)
    values = theta * prob.scales
    std_curv = {n: float(s) for n, s in zip(names, std)}
    replicates = None
    if bootstrap > 0:
        replicates = _bootstrap(prob, S0, theta, sigma, bootstrap,
                                rng if rng is not None else np.random.default_rng(0), max_nfev)
        std = replicates.std(axis=0, ddof=1)
        corr = np.corrcoef(replicates, rowvar=False).reshape(k, k)
    out, _ = prob.simulate(S0, theta)
    resid = out - meas
    chans = _channel_names(model, prob.meas_rows)
    rms_fit = {c: float(np.sqrt(np.mean(resid[:, i] ** 2))) for i, c in enumerate(chans)}
    head = max(3, int(round(head_share * (K - 1))) + 1)
    rms_val, trace = _validate(model, rec, names, theta, prob.scales, last, K, head)
    nominal_theta = np.array([model.nominal[nm] for nm in names]) / prob.scales
    rms_nom, trace_nom = _validate(model, rec, names, nominal_theta, prob.scales, last, K, head)
    if trace:
        trace["predicted_nominal"] = trace_nom["predicted"]
    return Fit(names=names, values={n: float(v) for n, v in zip(names, values)},
               nominal={n: model.nominal[n] for n in names},
               std={n: float(s) for n, s in zip(names, std)}, correlation=corr,
               noise_std={c: float(s) for c, s in zip(chans, sigma)}, rms_fit=rms_fit,
               rms_validation=rms_val, rms_validation_nominal=rms_nom, iterations=total,
               segments=len(starts), segment_s=(K - 1) * rec.dt,
               train_s=float(rec.t[last - 1] - rec.t[0]),
               validation_s=float(rec.t[-1] - rec.t[last]), status=r.message.strip(),
               validation_trace=trace, uncertainty="bootstrap" if bootstrap > 0 else "curvature",
               replicates=replicates, std_curvature=std_curv)


def _bootstrap(prob: _Problem, S0: np.ndarray, theta: np.ndarray, sigma: np.ndarray,
               replicates: int, rng: np.random.Generator, max_nfev: int) -> np.ndarray:
    """``replicates`` refits, each on the segments drawn with replacement (the same
    weights; warm-started at the fit): the estimates, replicates x parameters."""
    nseg = len(prob.starts)
    if nseg < 2:
        raise ScenarioError("--uncertainty bootstrap: needs at least 2 training segments "
                            "(a longer record or a shorter --segment)")
    out = np.empty((replicates, prob.k))
    for b in range(replicates):
        idx = rng.integers(0, nseg, nseg)
        sub = _Problem(prob.model, prob.rec, prob.names, [prob.starts[i] for i in idx], prob.K,
                       len(prob.meas_rows) > prob.dof)
        _, th, r = _solve(sub, S0[idx], theta, sigma, True, max_nfev)
        if r.status <= 0:
            raise FitFailed(f"bootstrap replicate {b}: the refit did not converge "
                            f"({r.message.strip()})")
        out[b] = th * prob.scales
    return out
