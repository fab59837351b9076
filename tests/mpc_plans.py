"""Run ``mpc`` and keep every plan it solved: what the constraint tests check."""

from __future__ import annotations

from tspend import run
from tspend.controllers.mpc import MPCController


def run_keeping_plans(monkeypatch, scenario):
    """``(result, plans)``: each successful solve's (planned states, planned inputs, state
    lower and upper bounds), in order."""
    plans = []
    solve = MPCController.solve

    def recording(self, state, ref):
        out = solve(self, state, ref)
        if out[1]:
            plans.append((self.plan_states.copy(), self.plan_inputs.copy(),
                          self.state_lo.copy(), self.state_hi.copy()))
        return out

    monkeypatch.setattr(MPCController, "solve", recording)
    return run(scenario, controller="mpc"), plans
