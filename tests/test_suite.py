"""The suite: every registered plant kind (of every domain) x every controller kind.

Built from the registries (tspend.plants.registry.PLANT_KINDS, tspend.controllers.KINDS),
so a new domain or controller kind is covered with no new test.  Each pair is built from
the first scenario of that plant kind, run for one second, and checked: finite, the
plant's full state named and unitful, the recording written and read back equal to the
run's own history.
"""

from __future__ import annotations

import tomllib

import numpy as np
import pytest

from tspend import load_scenario, override
from tspend.controllers import KINDS, unsupported
from tspend.runtime.errors import ScenarioError
from tspend.loop.simulation import build_controller, build_plant, run
from tspend.plants.registry import DOMAINS, PLANT_KINDS
from tspend.recorder import RerunSink, close_recording, open_recording, read_scalar_series
from tspend.scenario import available_scenarios
from tspend.task import TERMINATIONS, build_task


def _scenario_of(kind: str) -> str | None:
    """The plant kind's plain scenario: no effects; one on the domain's default model
    first (the articulated domain has many machines), then a file named after the backend
    (pendulum_mujoco before pendulum_friction)."""
    backend = kind.rpartition("_")[2]
    default = PLANT_KINDS[kind].domain.default_model

    def rank(p):
        model = tomllib.loads(p.read_text()).get("plant", {}).get("model", "")
        return (bool(default) and model != default, not p.stem.endswith(backend), p.name)

    for path in sorted(available_scenarios(), key=rank):
        plant = tomllib.loads(path.read_text()).get("plant", {})
        if plant.get("kind") == kind and not tomllib.loads(path.read_text()).get("effects"):
            return str(path)
    return None


SCENARIOS = {kind: _scenario_of(kind) for kind in PLANT_KINDS}


def test_every_domain_has_a_scenario_of_each_kind() -> None:
    assert set(DOMAINS) >= {"cartpole", "furuta", "nonaffine", "duffing", "third_order"}
    missing = [k for k, s in SCENARIOS.items() if s is None]
    assert not missing, f"plant kinds without a scenario: {missing}"


@pytest.mark.parametrize("plant_kind", sorted(PLANT_KINDS))
def test_plant_names_its_full_state(plant_kind: str) -> None:
    scn = load_scenario(SCENARIOS[plant_kind])
    plant = build_plant(scn)
    names, units = tuple(plant.state_names), tuple(plant.state_units)
    assert len(names) == len(units) == plant.full_state().size >= plant.order
    assert len(set(names)) == len(names) and all(names)
    domain = PLANT_KINDS[plant_kind].domain
    assert set(domain.view_names(plant)) <= set(names)
    # the view the controller sees is the full state's view entries
    task = build_task(plant)
    assert tuple(names[i] for i in task.view_index) == tuple(domain.view_names(plant))


@pytest.mark.parametrize("controller", sorted(KINDS))
@pytest.mark.parametrize("plant_kind", sorted(PLANT_KINDS))
def test_every_kind_runs_on_every_domain(plant_kind: str, controller: str, tmp_path) -> None:
    scn = override(load_scenario(SCENARIOS[plant_kind]), **{"run.duration": 1.0,
                                                             "run.snapshot_every": 0.5})
    # a kind declares what it needs of a domain (Controller.needs, .domains): where the
    # domain does not provide it, the kind refuses with that one line (exit 2 on the CLI)
    # and the pair is skipped with the declared reason
    why = unsupported(scn, controller)
    if why is not None:
        with pytest.raises(ScenarioError) as refused:
            build_controller(scn, kind=controller)
        assert str(refused.value) == why and "\n" not in why
        pytest.skip(why)
    # a learned policy runs only where the scenario names one ([controllers.policy] path)
    if controller == "policy" and "policy" not in dict(scn.controllers):
        with pytest.raises(ScenarioError, match="controllers.policy.path: not set") as refused:
            build_controller(scn, kind=controller)
        pytest.skip(str(refused.value))
    # a kind that cannot serve this particular machine (not the domain: wang_indirect keeps
    # g_hat > 0 and a model whose df/du < 0 at the upright, as a chain on a cart pushed
    # toward +x can have) refuses it in one line naming itself and the figure
    if controller == "wang_indirect" and PLANT_KINDS[plant_kind].domain.name == "articulated":
        try:
            build_controller(scn, kind=controller)
        except ScenarioError as refused:
            assert "\n" not in str(refused) and f"controllers.{controller}:" in str(refused)
            pytest.skip(str(refused))
    path = tmp_path / "run.rrd"
    rec = open_recording("suite", mode="save", path=path)
    sink = RerunSink(rec)
    result = run(scn, sinks=[sink], controller=controller)
    sink.close()
    close_recording(rec)
    # a controller that drops the pole is a result, not a failure of the suite: the task
    # ends the run (docs/architecture.md); anything else (diverged, failed) is a defect
    assert result.status in ("completed", *TERMINATIONS), result.end.message
    h = result.history
    steps = h["x"].shape[0]
    assert h["x"].shape[1] == PLANT_KINDS[plant_kind].order and 0 < steps <= 1000
    assert result.status != "completed" or steps == 1000
    assert np.isfinite(h["x"]).all() and np.isfinite(h["u"]).all()
    t, x1 = read_scalar_series(path, "series/tracking", 1)
    assert np.array_equal(x1, h["x"][:, 0]) and t.size == steps

