"""References a rig needs (issue 12): set-points through a reference model, and a recorded
reference read from CSV.  The oracle is ``scipy.signal.lsim`` of the reference model
``w^n / (s + w)^n`` and of ``w^n s^k / (s + w)^n`` for the k-th derivative."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy import signal

from tspend import load_scenario, override, run
from tspend.runtime.errors import ScenarioError
from tspend.config.signals import CsvReference, StepSequence


def lsim_derivatives(t: np.ndarray, v: np.ndarray, n: int, w: float) -> np.ndarray:
    den = np.poly([-w] * n)
    out = []
    for k in range(n + 1):
        num = np.zeros(k + 1)
        num[0] = w ** n
        out.append(signal.lsim((num, den), v, t, X0=None, interp=True)[1])
    return np.column_stack(out)


@pytest.mark.parametrize("n", [2, 3])
def test_step_sequence_is_the_reference_model_response(n: int) -> None:
    ref = StepSequence(times=(0.5, 2.0), values=(0.1, -0.05), initial=0.0, omega=3.0)
    t = np.arange(0.0, 5.0, 1e-4)
    v = np.where(t < 0.5, 0.0, np.where(t < 2.0, 0.1, -0.05))
    got = ref.derivatives(t, n)
    want = lsim_derivatives(t, v, n, 3.0)
    away = (np.abs(t - 0.5) > 2e-3) & (np.abs(t - 2.0) > 2e-3)
    for k in range(n + 1):
        scale = np.abs(want[:, k]).max()
        assert np.abs(got[away, k] - want[away, k]).max() < 2e-3 * scale, k
    # r .. r^(n-1) are continuous through the steps; r^(n) jumps by w^n times the step
    i = np.searchsorted(t, 0.5)
    assert abs(got[i, n] - got[i - 1, n]) == pytest.approx(3.0 ** n * 0.1, rel=1e-9)
    assert all(abs(got[i, k] - got[i - 1, k]) < 1e-3 for k in range(n))


def test_csv_reference_matches_the_filter(tmp_path: Path) -> None:
    csv = tmp_path / "ref.csv"
    tt = np.linspace(0.0, 4.0, 81)
    vv = 0.1 * np.sin(1.5 * tt) + 0.05 * (tt > 2.0)
    csv.write_text("time,value\n" + "".join(f"{float(a)!r},{float(b)!r}\n" for a, b in zip(tt, vv)))
    ref = CsvReference(path=str(csv), omega=8.0)
    t = np.arange(0.0, 4.0, 1e-3)
    got = ref.derivatives(t, 2)
    want = lsim_derivatives(t, np.interp(t, tt, vv), 2, 8.0)
    for k in range(3):
        assert np.abs(got[:, k] - want[:, k]).max() < 1e-3 * np.abs(want[:, k]).max() + 1e-9, k


def test_scenario_keys_for_steps_and_csv(tmp_path: Path) -> None:
    scn = load_scenario("pendulum_payload_step")
    assert isinstance(scn.reference, StepSequence) and scn.reference.values == (0.05, -0.05, 0.0)
    with pytest.raises(ScenarioError, match="reference.times: must be >= 0 and strictly increasing"):
        override(scn, **{"reference.times": [3.0, 1.0, 2.0]})
    with pytest.raises(ScenarioError, match="reference.times: times and values"):
        override(scn, **{"reference.values": [0.1]})
    csv = tmp_path / "r.csv"
    csv.write_text("time,value\n0,0\n1,0.05\n2,0.05\n")
    s = override(load_scenario("ex3_pendulum_ode"),
                 **{"reference": {"kind": "csv", "path": str(csv)}, "run.duration": 2.0})
    r = run(s)
    assert r.status == "completed" and r.history["ref"][-1, 0] == pytest.approx(0.05, abs=1e-4)
    with pytest.raises(ScenarioError, match="reference.path: cannot use"):
        override(s, **{"reference": {"kind": "csv", "path": str(tmp_path / "none.csv")}})
