"""A controller of your own, run by tspend without changing the package: copy this file.

    tspend run ex3_pendulum_ode --controller examples/custom_controller.py:SaturatedPD
    tspend run pendulum_mujoco --controller examples/custom_controller.py:SaturatedPD \
        --set controllers.saturated_pd.kp=3000 --metrics m.json

What tspend gives it and wants back (docs/writing-a-controller.md has the whole story):

- it is built once per run as ``SaturatedPD(scenario, settings)``: ``settings`` is the
  ``Settings`` below, read from the scenario's ``[controllers.saturated_pd]`` table and
  ``--set controllers.saturated_pd.KEY=VALUE``, checked like a built-in kind's;
- ``reset(rng)`` before the first sample (draw anything random from ``rng`` only);
- ``step(obs, dt)`` every sample gets an Observation: ``obs.x``, the task's view of the
  state (on the cart-pole ``[hinge, hinge_dot]``), ``obs.ref``, the reference and its
  derivatives ``[r, r', r'']``, ``obs.state`` the plant's full state named by
  ``obs.names`` (``obs.get("slider")``), ``obs.t`` the time.  It returns the control u
  (on the cart-pole the force on the cart, N) and may write its diagnostics into
  ``self.diag``, which are recorded by name.
"""

from dataclasses import dataclass

import numpy as np

from tspend.controllers.base import Controller, Observation, diag_width, diagnostics
from tspend.controllers.settings import KindSettings, setting


@dataclass(frozen=True)
class Settings(KindSettings):
    """``[controllers.saturated_pd]``: each key's default, unit and meaning."""

    kp: float = setting(2000.0, "N per rad of angle error", low=0.0)
    kd: float = setting(500.0, "N per rad/s of rate error", low=0.0)
    k_cart: float = setting(0.0, "N per m of cart position, if the plant has a 'slider'",
                            low=0.0)
    u_max: float = setting(300.0, "N; |u| never exceeds it", low=0.0, strict=True)


class SaturatedPD(Controller):
    """PD on the tracking error, clipped to +/- u_max (an example plug-in)."""

    kind = "saturated_pd"  # what the metrics JSON's controller.kind and the recording say
    Settings = Settings

    def __init__(self, scenario, settings: Settings) -> None:
        self.settings = settings
        self.order = len(scenario.plant.x0)  # n: obs.x has n entries, obs.ref n + 1
        self.diagnostics = diagnostics(
            ("u_unclipped", 1, {"panel": "control", "unit": "N",
                                "description": "the PD law before the clip"}))
        self.diag = np.zeros(diag_width(self.diagnostics))

    def reset(self, rng: np.random.Generator) -> None:
        """Nothing to forget and nothing random."""

    def step(self, obs: Observation, dt: float) -> float:
        s = self.settings
        e = obs.x - obs.ref[: self.order]  # [e, e'] = x - r
        u = -(s.kp * e[0] + s.kd * e[1])
        if s.k_cart and "slider" in obs.names:
            u -= s.k_cart * obs.get("slider")
        self.diag[0] = u
        return float(np.clip(u, -s.u_max, s.u_max))
