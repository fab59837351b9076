"""Real-world effects between the controller and the plant (docs/testbed.md).

All are scenario options (``[effects]``), off by default, and act identically on every
backend because they sit outside it:

* on the way in (:class:`EffectsPlant`, a Plant around the plant): actuator rate limit
  then saturation, a change of M, m, l at a given time;
* a finite rail (``rail``) is a termination of the task: it overrides the slide joint's
  range (:mod:`tspend.task`), and the run ends ``rail_end``;
* on the way out (:class:`Measurement`, the runner's per-sample hook): a measurement
  delay of k samples, seeded white sensor noise per state from its own random stream,
  and the cart-centring outer loop that shapes the pole reference.

Viscous and dry friction are plant parameters (``[plant] cart_damping`` ...), because
they are physics inside the integration step; these are not (neither the plant's state,
inputs nor parameters, but what stands between it and the controller), so they live
beside :mod:`tspend.task`, not under ``tspend/plants/``.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import replace
from typing import Any

import numpy as np

from tspend.config import EffectsConfig, OuterLoopConfig
from tspend.plants.base import CartPolePlant, InputInfo, JointInfo, Plant, TaskDefaults, read_as
from tspend.plants.domain import CAPABILITIES, CART_CENTRING, PARAMETER_CHANGE, Domain


__all__ = ["EffectsPlant", "Measurement", "OuterLoop", "needs_hook", "needs_plant_wrapper",
           "unsupported"]


class EffectsPlant(Plant):
    """``plant`` seen through an actuator, and changed at a given time.

    Forwards the plant interface to the inner plant; the inputs' bounds are the
    saturation's when it is tighter.
    """

    def __init__(self, plant: Plant, cfg: EffectsConfig) -> None:
        self.inner, self.cfg = plant, cfg
        self.order = plant.order
        self._u_prev = 0.0
        self._t = 0.0
        self._changed = False

    # the inner plant's compiled step would bypass the effects: the base's None stays

    @property
    def params(self) -> Any:
        """The inner machine's parameters; AttributeError for a plant that has none, as on
        the plant itself (what a wrapper forwards is the inner plant's own attribute)."""
        return getattr(self.inner, "params")

    def underlying(self) -> Plant:
        """The plant behind the effects: what its domain reads of it (its machine, its
        numbers), through :func:`tspend.plants.base.read_as`."""
        return self.inner.underlying()

    @property
    def name(self) -> str:  # type: ignore[override]
        return self.inner.name

    @property
    def domain(self) -> str:  # type: ignore[override]
        return self.inner.domain

    @property
    def state_names(self) -> tuple[str, ...]:
        return self.inner.state_names

    @property
    def state_units(self) -> tuple[str, ...]:
        return self.inner.state_units

    def full_state(self) -> np.ndarray:
        return self.inner.full_state()

    @property
    def joints(self) -> tuple[JointInfo, ...]:
        return self.inner.joints

    @property
    def inputs(self) -> tuple[InputInfo, ...]:
        sat = self.cfg.saturation
        if sat <= 0.0:
            return self.inner.inputs
        return tuple(replace(i, lo=max(i.lo, -sat), hi=min(i.hi, sat))
                     for i in self.inner.inputs)

    def parameters(self) -> dict[str, float]:
        return self.inner.parameters()

    def mj_model(self) -> Any:
        # the effects act on u and the measurement, not on the model MuJoCo differentiates
        return self.inner.mj_model()

    def default_task(self) -> TaskDefaults:
        return self.inner.default_task()

    @property
    def gain_sign(self) -> int:
        return self.inner.gain_sign

    def check_sample_time(self, dt: float) -> None:
        self.inner.check_sample_time(dt)

    def departures(self, dt: float | None = None) -> list[str]:
        return self.inner.departures(dt)

    def reset(self, x0: np.ndarray) -> None:
        self.inner.reset(x0)
        self._u_prev, self._t, self._changed = 0.0, 0.0, False

    def applied(self, u: float, dt: float) -> float:
        """The force the actuator delivers for the command u: rate limit, then saturation."""
        c = self.cfg
        if c.rate_limit > 0.0:
            step = c.rate_limit * dt
            u = min(max(u, self._u_prev - step), self._u_prev + step)
        if c.saturation > 0.0:
            u = min(max(u, -c.saturation), c.saturation)
        return u

    def step(self, u: float, d: float, dt: float) -> None:
        change = self.cfg.change
        if change is not None and not self._changed and self._t >= change.at - 0.5 * dt:
            inner = read_as(self.inner, CartPolePlant)
            p = inner.params
            inner.set_params(replace(p, M=change.M or p.M, m=change.m or p.m, l=change.l or p.l,
                                     J=0.0))
            self._changed = True
        if math.isfinite(u):
            u = self.applied(u, dt)
        self._u_prev = u
        self.inner.step(u, d, dt)
        self._t += dt

    def extras(self) -> dict[str, float]:
        out = dict(self.inner.extras())
        if self.cfg.saturation > 0.0 or self.cfg.rate_limit > 0.0:
            out["u_applied"] = self._u_prev
        return out


class OuterLoop:
    """Cart centring by the pole reference (docs/testbed.md, equations (O1)-(O2)).

    ``c = a tanh(theta_sign (k_x x_c + k_v x_c') / a)``, a = max_angle (O1), is the lean that
    brings the cart back (a pole held at theta accelerates the cart by -g tan theta);
    it is smoothed by ``w^n / (s + w)^n``, w = 1/tau (O2), whose states give the added
    reference and its n derivatives, discretised exactly for c held over a sample.
    """

    def __init__(self, cfg: OuterLoopConfig, n: int, dt: float, theta_sign: float) -> None:
        from scipy.linalg import expm

        self.cfg, self.n, self.sign = cfg, n, theta_sign
        w = 1.0 / cfg.tau
        A = np.zeros((n, n))
        A[:-1, 1:] = np.eye(n - 1)
        A[-1, :] = -np.array([math.comb(n, k) * w ** (n - k) for k in range(n)])
        b = np.zeros(n)
        b[-1] = w ** n
        big = np.zeros((n + 1, n + 1))
        big[:n, :n], big[:n, n] = A * dt, b * dt
        E = expm(big)
        self.Phi, self.gamma, self.A, self.b = E[:n, :n], E[:n, n], A, b
        self.z = np.zeros(n)

    def shape(self, ref_row: np.ndarray, cart_pos: float, cart_vel: float) -> None:
        c = self.cfg
        # a smooth limit: a clip's kink would put a jump into r^(n)'s derivative
        cmd = c.max_angle * math.tanh(self.sign * (c.k_x * cart_pos + c.k_v * cart_vel)
                                      / c.max_angle)
        z = self.z
        ref_row[: self.n] += z
        ref_row[self.n] += float(self.A[-1] @ z + self.b[-1] * cmd)
        self.z = self.Phi @ z + self.gamma * cmd


class Measurement:
    """The runner's per-sample hook: what the controller sees, and the shaped reference."""

    def __init__(self, cfg: EffectsConfig, plant: Plant, dt: float, seed: int) -> None:
        self.cfg, self.plant = cfg, plant
        n = plant.order
        std = np.asarray(cfg.noise_std or (0.0,) * n, dtype=float)
        self.std = std if np.any(std > 0.0) else None
        # its own stream, so the controller's draws (and every noiseless result) stay put
        self.rng = np.random.default_rng(cfg.noise_seed or (seed, 0x5E4502))
        self.past: deque[np.ndarray] = deque(maxlen=cfg.delay + 1)
        ol = cfg.outer_loop
        on = ol is not None and (ol.k_x != 0.0 or ol.k_v != 0.0)
        self.outer = OuterLoop(ol, n, dt, read_as(plant, CartPolePlant).params.theta_sign) \
            if on else None

    def __call__(self, t: float, x: np.ndarray, ref_row: np.ndarray) -> np.ndarray:
        if self.outer is not None:
            extras = self.plant.extras()
            self.outer.shape(ref_row, extras.get("cart_pos", 0.0), extras.get("cart_vel", 0.0))
        seen = x
        if self.cfg.delay:
            if not self.past:
                self.past.extend([x] * (self.cfg.delay + 1))
            self.past.append(x)
            seen = self.past[0]
        if self.std is not None:
            seen = seen + self.std * self.rng.standard_normal(seen.size)
        return seen


def unsupported(cfg: EffectsConfig, domain: Domain) -> str | None:
    """Why ``cfg`` cannot act on a plant of ``domain`` (None: it can): ``change`` needs
    a domain whose parameters change during a run, the outer loop a cart to centre
    (:attr:`tspend.plants.domain.Domain.provides`), ``rail`` a rail joint
    (:attr:`tspend.plants.domain.Domain.rail_joint`)."""
    if cfg.rail > 0.0 and not domain.rail_joint:
        return (f"effects.rail: the {domain.name} domain has no rail (a slide joint); bound a "
                f"state with [task.state_bounds] instead")
    ol = cfg.outer_loop
    wanted = [("effects.change", PARAMETER_CHANGE, cfg.change is not None),
              ("effects.outer_loop", CART_CENTRING,
               ol is not None and (ol.k_x != 0.0 or ol.k_v != 0.0))]
    for key, capability, on in wanted:
        if on and capability not in domain.provides:
            return (f"{key}: the {domain.name} domain does not support it (it needs "
                    f"{CAPABILITIES[capability]})")
    return None


def needs_hook(cfg: EffectsConfig) -> bool:
    ol = cfg.outer_loop
    return bool(cfg.delay or (cfg.noise_std and any(s > 0 for s in cfg.noise_std))
                or (ol is not None and (ol.k_x or ol.k_v)))


def needs_plant_wrapper(cfg: EffectsConfig) -> bool:
    return bool(cfg.saturation or cfg.rate_limit or cfg.change is not None)
