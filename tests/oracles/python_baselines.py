"""Test oracle: the baselines' previous Python steps (numpy, before they were compiled).

Each function returns a :class:`~tspend.controllers.base.Controller` that takes its
numbers from a built controller of the kind but steps with the law as it was written in
numpy before the kind got a compiled step (``git show 504fb01:tspend/controllers/KIND.py``);
it offers no compiled step, so the runner's generic loop runs it.  The compiled kinds must
match these over whole runs (tests/test_compiled_baselines.py).
"""

from __future__ import annotations

import math
from functools import reduce

import numpy as np

from tspend.controllers.base import Controller, Observation


class _Oracle(Controller):
    """Wraps a built controller: its numbers, diagnostics and diag; the old ``step``."""

    def __init__(self, built: Controller) -> None:
        self.built = built
        self.kind = built.kind
        self.order = built.order
        self.diagnostics = built.diagnostics
        self.diag = built.diag

    def reset(self, rng: np.random.Generator) -> None:
        self.built.reset(rng)

    def parameters(self) -> dict[str, np.ndarray]:
        return self.built.parameters()


class PD(_Oracle):
    def step(self, obs: Observation, dt: float) -> float:
        c = self.built
        x, ref = obs.x, obs.ref
        n = c.order
        e = x - ref[:n]
        u_ff = ref[n] / c.b0
        u_fb = -float(c.k @ e) / c.b0
        self.diag[0], self.diag[1] = u_ff, u_fb
        return u_ff + u_fb


class ViewLQR(_Oracle):
    def step(self, obs: Observation, dt: float) -> float:
        c = self.built
        x, ref = obs.x, obs.ref
        n = c.order
        r = ref[:n]
        e = x - r
        u_ff = c.u_op + (ref[n] - float(c.a @ (r - c.x_op))) / c.b
        u_fb = -float(c.K @ e)
        d = self.diag
        d[0], d[1], d[2] = u_ff, u_fb, float(e @ c.P @ e)
        return u_ff + u_fb


def _sat(z: float) -> float:
    return z if -1.0 <= z <= 1.0 else (1.0 if z > 0.0 else -1.0)


class SlidingMode(_Oracle):
    def step(self, obs: Observation, dt: float) -> float:
        c = self.built
        x, ref = obs.x, obs.ref
        n = c.order
        c_shift = np.zeros(n)
        c_shift[1:] = c.c[:-1]
        e = x - ref[:n]
        s = float(c.c @ e)
        f_hat = float(c.a @ (x - c.x_op))
        u_eq = c.u_op + (ref[n] - f_hat - float(c_shift @ e)) / c.b0
        u_sw = -c.k * _sat(s / c.phi) / c.b0
        d = self.diag
        d[0], d[1], d[2], d[3] = s, s / c.phi, u_eq, u_sw
        return u_eq + u_sw


def gaussian_basis(grid, x: np.ndarray) -> np.ndarray:
    """Wang and Mendel's basis in numpy (the previous ``gaussian_basis.basis``)."""
    z = np.minimum(np.maximum(x, grid.lo), grid.hi)[grid.owner]
    mu = np.exp(-np.square((z - grid.flat_centres) / grid.flat_sigma))
    mu = [mu[s] for s in grid.slices]
    g = np.outer(mu[0], mu[1]).ravel() if len(mu) == 2 else reduce(np.multiply.outer, mu).ravel()
    return g / g.sum()


class WangIndirect(_Oracle):
    """Steps its own theta_f, theta_g (copies of the built controller's)."""

    def __init__(self, built: Controller) -> None:
        super().__init__(built)
        self.theta_f = built.theta_f.copy()
        self.theta_g = built.theta_g.copy()

    def reset(self, rng: np.random.Generator) -> None:
        self.built.reset(rng)
        self.theta_f = self.built.theta_f.copy()
        self.theta_g = self.built.theta_g.copy()

    def parameters(self) -> dict[str, np.ndarray]:
        return {"theta_f": self.theta_f.copy(), "theta_g": self.theta_g.copy()}

    def supervisory(self, e_delta, V, f_hat, g_hat, u_c) -> float:
        sv = self.built.supervisor
        if sv is None or V <= sv.V_bar or e_delta == 0.0:
            return 0.0
        size = (abs(f_hat) + sv.f_upper + abs(g_hat * u_c) + sv.g_upper * abs(u_c)) / sv.g_lower
        return -math.copysign(size, e_delta)

    def step(self, obs: Observation, dt: float) -> float:
        c = self.built
        x, ref = obs.x, obs.ref
        n = c.order
        e = x - ref[:n]
        e_delta = float(c.P[n - 1] @ e)
        V = 0.5 * float(e @ c.P @ e)
        xi = gaussian_basis(c.grid, x)
        f_hat = float(self.theta_f @ xi)
        g_hat = float(self.theta_g @ xi)
        u_c = (-f_hat + ref[n] - float(c.lam @ e)) / g_hat
        u_s = self.supervisory(e_delta, V, f_hat, g_hat, u_c)
        d = self.diag
        d[0], d[1], d[2], d[3], d[4], d[5] = u_c, u_s, f_hat, g_hat, e_delta, V
        d[6], d[7] = math.sqrt(self.theta_f @ self.theta_f), self.theta_g.min()
        a_f, a_g = c.gamma_f * e_delta, c.gamma_g * e_delta * u_c
        self.theta_f += (dt * a_f) * xi
        self.theta_g += (dt * a_g) * xi
        if a_g < 0.0 or c.f_radius > 0.0 or c.g_radius > 0.0:
            np.maximum(self.theta_g, c.g_min, out=self.theta_g)
            for theta, radius in ((self.theta_f, c.f_radius), (self.theta_g, c.g_radius)):
                if radius > 0.0:
                    norm = float(np.linalg.norm(theta))
                    if norm > radius:
                        theta *= radius / norm
            if c.g_radius > 0.0:
                np.maximum(self.theta_g, c.g_min, out=self.theta_g)
        return u_c + u_s


def _df_du(model, t, x, u, h_rel=1e-6) -> float:
    h = h_rel * (1.0 + abs(u))
    return (model.accel(t, x, u + h, 0.0) - model.accel(t, x, u - h, 0.0)) / (2.0 * h)


def solve_for_u(model, t, x, v, u0, tol, max_iter):
    """The previous Newton solver: ``(u, iterations, residual)``, None when it fails."""
    f = lambda w: model.accel(t, x, w, 0.0)  # noqa: E731
    if model.affine_in_u:
        f0 = f(0.0)
        u = (v - f0) / (f(1.0) - f0)
        return u, 0, f(u) - v
    u = u0
    res = f(u) - v
    scale = tol * (1.0 + abs(v))
    for it in range(1, max_iter + 1):
        if abs(res) <= scale:
            return u, it - 1, res
        slope = _df_du(model, t, x, u)
        if slope == 0.0 or not math.isfinite(slope):
            break
        step = res / slope
        for _ in range(60):
            try:
                trial = f(u - step) - v
            except OverflowError:
                trial = math.inf
            if abs(trial) < abs(res):
                break
            step *= 0.5
        else:
            break
        u, res = u - step, trial
    if abs(res) <= scale:
        return u, max_iter, res
    return None


class FeedbackLinearization(_Oracle):
    def __init__(self, built: Controller) -> None:
        super().__init__(built)
        self.k, self.u_prev = 0, built.model.u_op

    def step(self, obs: Observation, dt: float) -> float:
        c = self.built
        x, ref = obs.x, obs.ref
        n = c.order
        t = self.k * dt
        self.k += 1
        e = x - ref[:n]
        v = ref[n] - float(c.lam @ e)
        found = solve_for_u(c.model, t, x, v, self.u_prev, c.tol, c.max_iter)
        u, its, res = found if found is not None else (math.nan, c.max_iter, math.nan)
        d = self.diag
        d[0], d[2], d[3] = v, its, res
        d[1] = _df_du(c.model, t, x, u) if math.isfinite(u) else math.nan
        self.u_prev = u if math.isfinite(u) else self.u_prev
        return u


class SwingUp(_Oracle):
    """The previous numpy swing-up; its catching LQR is the kind's own full-state law
    (compiled since before, and tested against the Riccati solution elsewhere)."""

    def __init__(self, built: Controller) -> None:
        super().__init__(built)
        self.mode = 0.0

    def reset(self, rng: np.random.Generator) -> None:
        self.built.reset(rng)
        self.mode = 0.0

    def swing(self, state):
        c = self.built
        m, s = c.model, c.s
        dof, act = m.dof, m.actuated
        f = m.numeric
        a0 = np.asarray(f(state, 0.0), dtype=float)
        du = np.asarray(f(state, 1.0), dtype=float) - a0
        slope = state[dof + m.pole] * du[m.pole] * math.copysign(1.0, du[act])
        sign = 1.0 if slope >= 0.0 else -1.0
        energy = m.energy(state)
        a = min(s.accel_max, max(-s.accel_max, s.energy_gain * (0.0 - energy) * sign))
        x, v = state[act], state[dof + act]
        k_x, k_v = s.centring
        a_c = -k_x * x - k_v * v
        if a_c * sign >= 0.0:
            a += a_c
        lim = min(m.q_hi[act], -m.q_lo[act])
        if math.isfinite(lim):
            stop = x + v * abs(v) / (2.0 * s.accel_max)
            if abs(stop) > lim - s.range_margin:
                a = -math.copysign(s.accel_max, v) if x * v > 0.0 else a_c
        u = (a - a0[act]) / du[act]
        return min(m.u_hi, max(m.u_lo, u)), a, energy

    def step(self, obs: Observation, dt: float) -> float:
        c = self.built
        m, s, state = c.model, c.s, obs.state
        theta = float(state[m.pole]) - 2.0 * math.pi * math.ceil((float(state[m.pole]) - math.pi)
                                                                / (2.0 * math.pi))
        if self.mode == 0.0 and abs(theta) < s.catch_angle:
            self.mode = 1.0
        elif self.mode == 1.0 and abs(theta) > s.release_angle:
            self.mode = 0.0
        energy = m.energy(state)
        if self.mode == 1.0:
            u = min(m.u_hi, max(m.u_lo, c.lqr.act(state, obs.ref)))
            a = 0.0
        else:
            u, a, _ = self.swing(state)
        d = self.diag
        d[0], d[1], d[2], d[3] = energy, self.mode, theta, a
        return u


#: kind -> the oracle of its previous Python step
ORACLES = {"pd": PD, "sliding_mode": SlidingMode, "wang_indirect": WangIndirect,
           "feedback_linearization": FeedbackLinearization, "swingup": SwingUp}


def oracle(built: Controller) -> Controller:
    """The previous Python step of the kind ``built`` is (the view design for ``lqr``)."""
    if built.kind == "lqr":
        return ViewLQR(built)
    return ORACLES[built.kind](built)
