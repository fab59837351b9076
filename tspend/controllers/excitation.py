"""``excited``: an identification input added to another controller's command.

    u = clip(u_inner(obs) + a(t) e(t), u_lo, u_hi)

``u_inner`` is the stabilising controller named by ``inner`` (default ``lqr``: the
cart-pole and the Furuta are unstable upright, so the excitation rides on a loop that
keeps them there), ``e(t)`` one of three classic identification signals of unit peak and
``a(t)`` the amplitude ramped in over ``ramp_s`` after ``start_s`` (Ljung, *System
Identification*, 2nd ed., 1999, section 13.3; Pintelon and Schoukens, 2012, ch. 5):

* ``multisine``: ``n_freq`` sines log-spaced over ``[f_min_hz, f_max_hz]`` with Schroeder
  phases (a low crest factor: most energy for a given peak), scaled to peak 1;
* ``chirp``: a logarithmic sweep from ``f_min_hz`` to ``f_max_hz`` over ``sweep_s``,
  repeated;
* ``prbs``: a pseudo-random binary sequence of +/-1 held ``1 / (2 f_max_hz)`` s per bit,
  drawn from ``seed``.

The clip keeps ``u`` inside the actuator's range (``u_lo``/``u_hi``, from the machine's
model: what the motor can take).  ``tspend excite`` writes a scenario with this kind and
sizes ``amplitude`` so that the motion stays well inside the rail and the task's bounds.
The excitation itself is a diagnostic (``u_exc``), so the recording shows it beside ``u``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from tspend.controllers.base import Controller, Diagnostic, Observation
from tspend.controllers.settings import KindSettings, setting, settings_for
from tspend.runtime.errors import ScenarioError

if TYPE_CHECKING:
    from tspend.plants.base import Plant
    from tspend.config import Scenario

__all__ = ["ExcitationSettings", "ExcitationSignal", "ExcitedController", "SIGNALS",
           "design_signal", "excitation", "build"]

SIGNALS = ("multisine", "chirp", "prbs")


@dataclass(frozen=True)
class ExcitationSettings(KindSettings):
    """``[controllers.excited]``."""

    inner: str = setting("lqr", "the stabilising controller kind the excitation rides on",
                         kind="string")
    signal: str = setting("multisine", "the identification input", kind="choice",
                          choices=SIGNALS)
    amplitude: float = setting(1.0, "peak of the excitation, in u's units", low=0.0)
    f_min_hz: float = setting(0.1, "lowest frequency, Hz", low=0.0, strict=True)
    f_max_hz: float = setting(3.0, "highest frequency, Hz", low=0.0, strict=True)
    n_freq: int = setting(16, "multisine: number of sines", kind="integer", low=1, high=1000)
    sweep_s: float = setting(10.0, "chirp: length of one sweep, s", low=0.0, strict=True)
    start_s: float = setting(0.5, "the excitation starts here, s", low=0.0)
    ramp_s: float = setting(1.0, "and reaches its amplitude this much later, s", low=0.0)
    seed: int = setting(0, "prbs: its bits' seed", kind="integer", low=0)
    u_lo: float = setting(-math.inf, "the actuator's least input (clip)")
    u_hi: float = setting(math.inf, "the actuator's largest input (clip)")

    def check(self, n: int):
        if self.f_max_hz <= self.f_min_hz:
            return "f_max_hz", f"must exceed f_min_hz ({self.f_min_hz:g})"
        if self.f_max_hz > MAX_BAND_RATIO * self.f_min_hz:
            # the multisine's peak is found on a grid of 160 f_max / f_min samples
            return "f_max_hz", (f"at most {MAX_BAND_RATIO:g} times f_min_hz ({self.f_min_hz:g}), "
                                f"got {self.f_max_hz:g}")
        if self.u_hi <= self.u_lo:
            return "u_hi", f"must exceed u_lo ({self.u_lo:g})"
        if self.inner == "excited":
            return "inner", "cannot be 'excited' itself"
        return None


@dataclass(frozen=True, eq=False)
class ExcitationSignal:
    """The excitation's frozen numbers, made once by :func:`design_signal`; :meth:`at` is
    its law (a controller step evaluates it every sample: nothing is drawn or searched
    there, 128 us a sample had been, a quarter of a 500 Hz rig's budget)."""

    settings: ExcitationSettings
    omega_rad_s: np.ndarray  # multisine: the lines' angular frequencies
    phase_rad: np.ndarray    # and their Schroeder phases
    inv_peak: float          # 1 / the multisine's peak over a long sample
    bits: np.ndarray         # prbs: its bits up to the horizon designed for

    def at(self, t: np.ndarray | float) -> np.ndarray:
        """``a(t) e(t)``: the excitation at times ``t`` (s)."""
        s = self.settings
        # ufuncs, not np.clip/np.where: a controller calls this on one float each sample
        t = np.asarray(t, dtype=float)
        started = t >= s.start_s
        tau = np.maximum(t - s.start_s, 0.0)
        ramp = np.minimum(tau / s.ramp_s, 1.0) * started if s.ramp_s > 0 else started * 1.0
        if s.signal == "multisine":
            e = np.sin(np.multiply.outer(tau, self.omega_rad_s) + self.phase_rad).sum(axis=-1)
            # log-spaced lines are not periodic: the peak over a long sample, and a clip for
            # the rare instant beyond it (the excitation never exceeds its amplitude)
            e = np.minimum(np.maximum(e * self.inv_peak, -1.0), 1.0)
        elif s.signal == "chirp":
            tt = np.mod(tau, s.sweep_s)
            r = s.f_max_hz / s.f_min_hz
            e = np.sin(2 * math.pi * s.f_min_hz * s.sweep_s / math.log(r) * (r ** (tt / s.sweep_s) - 1))
        else:
            idx = np.floor(tau / _prbs_hold_s(s)).astype(np.int64)
            needed = int(np.max(idx)) + 1 if idx.size else 1
            # past the horizon (a longer run than designed for) the same bits, drawn anew
            bits = self.bits if needed <= self.bits.size else _bits(s.seed, needed)
            e = 2.0 * bits[idx] - 1.0
        return s.amplitude * ramp * e


def design_signal(s: ExcitationSettings, horizon_s: float) -> ExcitationSignal:
    """The excitation's numbers for times up to ``horizon_s`` (s): the multisine's lines,
    phases and peak, the prbs's bits."""
    k = np.arange(1, s.n_freq + 1)
    omega = 2 * math.pi * np.geomspace(s.f_min_hz, s.f_max_hz, s.n_freq)
    phase = -math.pi * k * (k - 1) / s.n_freq                 # Schroeder
    inv_peak = 1.0 / _multisine_peak(s, omega, phase) if s.signal == "multisine" else 1.0
    n_bits = math.floor(max(horizon_s - s.start_s, 0.0) / _prbs_hold_s(s)) + 1
    bits = _bits(s.seed, n_bits) if s.signal == "prbs" else np.zeros(0, dtype=np.int64)
    return ExcitationSignal(s, omega, phase, inv_peak, bits)


def excitation(s: ExcitationSettings, t: np.ndarray | float) -> np.ndarray:
    """``a(t) e(t)``: the excitation at times ``t`` (s)."""
    return design_signal(s, float(np.max(t, initial=0.0))).at(t)


def _prbs_hold_s(s: ExcitationSettings) -> float:
    return 1.0 / (2.0 * s.f_max_hz)


#: the widest band of an excitation, f_max_hz / f_min_hz (four decades)
MAX_BAND_RATIO = 1e4


def _multisine_peak(s: ExcitationSettings, omega: np.ndarray, phase: np.ndarray) -> float:
    """The largest |sum of the lines| (``omega``, ``phase``) over four periods of the
    lowest, 40 samples per period of the highest (made once per design, not per sample)."""
    t = np.arange(0.0, 4.0 / s.f_min_hz, 1.0 / (40.0 * s.f_max_hz))
    return float(np.max(np.abs(np.sin(np.multiply.outer(t, omega) + phase).sum(-1))))


def _bits(seed: int, n: int) -> np.ndarray:
    # a fresh Generator each time: its first n bits are the same for every n (checked in
    # tests/test_identify.py), so a longer draw extends a shorter one
    return np.random.default_rng((seed, 0x1D3)).integers(0, 2, size=n)


class ExcitedController(Controller):
    """The ``excited`` kind: another kind's command plus the excitation."""

    kind = "excited"
    Settings = ExcitationSettings

    @classmethod
    def from_scenario(cls, scenario: "Scenario", machine: "Plant | None" = None) -> Controller:
        return build(scenario, machine)
    guarantees = "the inner kind's, for the excitation's amplitude small enough"

    def __init__(self, inner: Controller, signal: ExcitationSignal) -> None:
        self.inner, self.signal, self.s = inner, signal, signal.settings
        self.order = inner.order
        self.sample_period = inner.sample_period
        base = tuple(inner.diagnostics)
        w = max((d.start + d.width for d in base), default=0)
        self.diagnostics = base + (Diagnostic("u_exc", w, 1, panel="control",
                                              description="the identification input added to u"),)
        self.diag = np.zeros(w + 1)
        self._w = w

    def reset(self, rng: np.random.Generator) -> None:
        self.inner.reset(rng)

    def step(self, obs: Observation, dt: float) -> float:
        u = float(self.inner.step(obs, dt))
        e = float(self.signal.at(obs.t))
        if self._w:
            self.diag[: self._w] = self.inner.diag[: self._w]
        self.diag[self._w] = e
        return min(max(u + e, self.s.u_lo), self.s.u_hi)

    def parameters(self) -> dict[str, np.ndarray]:
        return self.inner.parameters()


def build(scenario: "Scenario", machine: "Plant | None" = None) -> ExcitedController:
    from tspend.controllers import build as build_kind

    s: ExcitationSettings = settings_for(scenario, ExcitationSettings)
    nyquist = nyquist_hz(scenario)
    if s.f_max_hz > nyquist:
        raise ScenarioError(f"{scenario.path or scenario.name}: controllers.excited.f_max_hz: "
                            f"{s.f_max_hz:g} Hz is above {nyquist:g} Hz, half the rate the "
                            f"input is applied at")
    return ExcitedController(build_kind(scenario, s.inner, machine=machine),
                             design_signal(s, scenario.run.duration))


def nyquist_hz(scenario: "Scenario") -> float:
    """Half the rate the input changes at (the control period, else the run's step): an
    excitation above it is aliased, not applied."""
    period = getattr(scenario.run, "control_period", 0.0) or scenario.run.dt
    return 0.5 / max(period, scenario.run.dt)
