"""Analytic plants against a tight solve_ivp solution under an open-loop input."""

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from tspend.task import build_task
from tspend.plants.analytic import duffing_plant, nonaffine_plant, third_order_plant
from cartpole_oracle import CartPoleParams, cartpole_ode_plant

DT = 1e-3


def _oracle(f, x0, u_fn, d_fn, steps, hidden=()):
    """Integrate piecewise over each sample with u, d held, by DOP853 at rtol 1e-12."""
    x = np.concatenate([x0, hidden]).astype(float)
    out = [x.copy()]
    for k in range(steps):
        t0 = k * DT
        u, d = u_fn(t0), d_fn(t0)
        sol = solve_ivp(lambda t, s: f(t, s, u, d), (t0, t0 + DT), x, method="DOP853",
                        rtol=1e-12, atol=1e-14)
        x = sol.y[:, -1]
        out.append(x.copy())
    return np.array(out)


def _chain(accel):
    def f(t, s, u, d):
        n = len(s)
        return np.concatenate([s[1:], [accel(t, s, u, d)]])
    return f


def _nonaffine(t, s, u, d):
    return 0.2 * (1 + math.exp(s[0] * s[1])) * (2 + math.sin(s[1])) * (u + math.exp(u) - 1) + d


def _duffing(t, s, u, d):
    return -0.1 * s[1] - s[0] ** 3 + 12 * math.cos(t) + u + d


def _third(t, s, u, d):
    return (-s[0] - 2 * s[1] - 1.5 * s[2] + 0.5 * math.sin(s[0]) * s[1]
            + (1.5 + math.cos(s[0])) * (u + 0.2 * math.tanh(u)) + d)


def _cartpole(p):
    def f(t, s, u, d):
        th, w, _, vc = s
        sn, cs = math.sin(th), math.cos(th)
        a = ((p.m * p.l * w * w * sn * cs - (p.M + p.m) * p.g * sn - u * cs + d)
             / (p.m * p.l * cs * cs - 4 / 3 * p.l * (p.M + p.m)))
        return [w, a, vc, (u + p.m * p.l * (cs * a - sn * w * w)) / (p.M + p.m)]
    return f


def _square(t):
    return 0.1 if (t % (2 * math.pi)) < math.pi else -0.1


def view(plant) -> np.ndarray:
    """The task's view of ``plant``'s full state (the tracked output and its derivatives)."""
    return plant.full_state()[build_task(plant).view_index]


CASES = [
    ("nonaffine", nonaffine_plant, _chain(_nonaffine), [0.2, 0.0], lambda t: 0.5 * math.sin(3 * t)),
    ("duffing", duffing_plant, _chain(_duffing), [0.3, 0.0], lambda t: 5 * math.sin(2 * t)),
    ("third_order", third_order_plant, _chain(_third), [0.1, 0.0, -0.2], lambda t: math.cos(t)),
]


@pytest.mark.parametrize("name,make,f,x0,u_fn", CASES, ids=[c[0] for c in CASES])
def test_analytic_plant_matches_solve_ivp(name, make, f, x0, u_fn):
    steps = 2000
    plant = make()
    plant.reset(np.array(x0))
    traj = [view(plant)]
    for k in range(steps):
        plant.step(u_fn(k * DT), _square(k * DT), DT)
        traj.append(view(plant))
    ref = _oracle(f, np.array(x0), u_fn, _square, steps)
    np.testing.assert_allclose(np.array(traj), ref[:, : len(x0)], atol=1e-8, rtol=0)


@pytest.mark.parametrize("params", [CartPoleParams(), CartPoleParams(5.0, 0.5, 1.0, 9.8),
                                    CartPoleParams(20.0, 2.0, 0.5, 9.81)])
def test_cartpole_ode_matches_solve_ivp(params):
    steps = 3000
    plant = cartpole_ode_plant(params)
    x0 = np.array([math.pi / 30, 0.0])
    plant.reset(x0)
    u_fn = lambda t: 20.0 * (params.M + params.m) / 11 * math.sin(1.3 * t)
    d_fn = lambda t: 0.05 if (t % (2 * math.pi)) < math.pi else -0.05
    traj = [np.concatenate([view(plant), list(plant.extras().values())])]
    for k in range(steps):
        plant.step(u_fn(k * DT), d_fn(k * DT), DT)
        traj.append(np.concatenate([view(plant), list(plant.extras().values())]))
    ref = _oracle(_cartpole(params), x0, u_fn, d_fn, steps, hidden=(0.0, 0.0))
    np.testing.assert_allclose(np.array(traj), ref, atol=1e-8, rtol=0)


def test_cartpole_sign_convention():
    """u > 0 gives theta'' > 0 at rest upright (docs/paper-notes.md section 7)."""
    plant = cartpole_ode_plant()
    plant.reset(np.zeros(2))
    plant.step(10.0, 0.0, DT)
    assert view(plant)[1] > 0
