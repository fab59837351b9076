"""tspend tune and the equal-budget comparison: the tuned scenario runs and reproduces its
score, the study resumes from its storage, bad input exits 2 with one line."""

from __future__ import annotations

import json
import math
import re
import tomllib

import numpy as np
import pytest

pytest.importorskip("optuna")

from tspend.cli.main import main  # noqa: E402
from tspend.scenario import available_scenarios, load_scenario, override  # noqa: E402
from tspend.studies import tune as tuning  # noqa: E402


@pytest.fixture(scope="module")
def executor():
    from tspend.sweep.executors import make_executor

    ex = make_executor(1)
    yield ex
    ex.close()


def _short(name: str, duration: float = 1.0):
    return override(load_scenario(name), **{"run.duration": duration})


def test_cli_tune_writes_a_runnable_scenario_that_reproduces_its_train_score(tmp_path, capsys,
                                                                             executor):
    from tspend.sweep import sweep

    out = tmp_path / "t.toml"
    status = main(["tune", "ex3_pendulum_ode", "--controller", "pd", "--trials", "3",
                   "--seeds", "0:2", "--test-seeds", "2:3", "--duration", "1", "--jobs", "1",
                   "--out", str(out)])
    assert status == 0
    printed = capsys.readouterr().out
    assert "train score (median rmse, seeds 0:2)" in printed and "test score" in printed
    text = out.read_text()
    doc = tomllib.loads(text)
    assert doc["run"]["duration"] == 1.0                    # the override is kept
    assert set(doc["controllers"]["pd"]) == {"bandwidth"}
    assert 0.2 <= doc["controllers"]["pd"]["bandwidth"] <= 1000.0
    assert doc["controllers"]["wang_indirect"] == {"gamma_f": 300.0}   # the original's table
    assert text.startswith('# tspend tune: controller = "pd", scenario = "ex3_pendulum_ode"')
    reported = float(re.search(r"# train score \(seeds 0-1\): (\S+);", text).group(1))
    rows = sweep(load_scenario(out), seeds=[0, 1], controllers=["pd"], executor=executor)
    assert tuning.score(rows, "rmse") == pytest.approx(reported, rel=1e-9)
    assert main(["run", str(out), "--controller", "pd", "--no-record"]) == 0


def test_paper_kind_is_tuned_in_its_controller_table_and_reproduces_exactly(tmp_path, executor):
    from tspend.sweep import sweep

    scn = _short("ex3_pendulum_ode", 0.5)
    r = tuning.tune(scn, "first_type", trials=2, seeds=[0, 1], test_seeds=[5],
                    executor=executor, defaults=False)
    path = tmp_path / "paper.toml"
    path.write_text(r.text)
    ctrl = tomllib.loads(r.text)["controller"]
    assert ctrl["adaptation"] == "first" and ctrl["eta"] == r.drawn["eta"]
    q = r.drawn["Q"]
    assert ctrl["Q"] == [[q, 0.0], [0.0, q]]
    p = r.drawn["lambda"]                                   # (s + p)^2 = s^2 + 2p s + p^2
    assert ctrl["lambda"] == pytest.approx([p * p, 2 * p], rel=1e-15)
    rows = sweep(load_scenario(path), seeds=[0, 1], controllers=["first_type"],
                 executor=executor)
    assert tuning.score(rows, "rmse") == r.train_score     # bit for bit


def test_storage_resumes_the_study(tmp_path, executor):
    scn = _short("ex3_pendulum_ode", 0.3)
    storage = str(tmp_path / "study.log")
    ran: list[int] = []
    first = tuning.tune(scn, "pd", trials=2, seeds=[0], executor=executor, storage=storage,
                        defaults=False, on_trial=lambda n, v: ran.append(n))
    assert ran == [0, 1] and first.trials == 2
    second = tuning.tune(scn, "pd", trials=3, seeds=[0], executor=executor, storage=storage,
                         defaults=False, on_trial=lambda n, v: ran.append(n))
    assert ran == [0, 1, 2] and second.trials == 3          # only the missing trial ran
    assert second.train_score <= first.train_score


def test_score_counts_runs_that_ended_badly_as_worst():
    import pandas as pd

    rows = pd.DataFrame({"status": ["completed", "fell", "failed", "completed", "diverged"],
                         "rmse": [1.0, 0.1, np.nan, 2.0, 0.2]})
    assert math.isinf(tuning.score(rows, "rmse"))          # 3 of 5 worst: the median is inf
    assert tuning.score(rows.iloc[[0, 1, 3]], "rmse") == 2.0


def test_every_scenario_reads_back_through_the_toml_writer():
    for path in available_scenarios():
        doc = tomllib.loads(path.read_text())
        assert tomllib.loads(tuning.dump_toml(doc)) == doc, path.name


def test_every_kind_declares_a_search_space_that_builds():
    from tspend.controllers import KINDS
    from tspend.controllers import search_space

    scn = load_scenario("ex3_pendulum_ode")
    for kind in KINDS:
        space = search_space(kind)
        if kind in ("policy", "excited"):
            # a learned policy's numbers are its weights (benchmarks/train_policy.py trains
            # them); the identification experiment's are its input's design, not gains
            assert space == {}
            continue
        assert space, kind
        mid = {k: (s.low * s.high) ** 0.5 if s.log else (s.low + s.high) / 2
               for k, s in space.items()}
        override(scn, **tuning.tuned_changes(scn, kind, mid))   # validates like the file


@pytest.mark.parametrize("argv, message", [
    (["--controller", "nope"], "unknown kind"),
    (["--trials", "0"], "--trials"),
    (["--seeds", "5:2"], "--seeds"),
    (["--test-seeds", "1:3"], "disjoint"),
    (["--metric", "speed"], "unknown metric"),
    (["--out", "other.toml"], "holds a tuned 'lqr' scenario"),
    (["--out", "mine.toml"], "was not written by tspend tune"),
    (["--out", "t.json"], "must end in .toml"),
])
def test_bad_input_exits_2_with_one_line(tmp_path, capsys, monkeypatch, argv, message):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "other.toml").write_text('# tspend tune: controller = "lqr", scenario = "x"\n')
    (tmp_path / "mine.toml").write_text("# my notes\n")
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    base = {"--controller": "pd", "--trials": "2", "--seeds": "0:2", "--out": "t.toml"}
    given = dict(zip(argv[::2], argv[1::2]))
    args = ["tune", "ex3_pendulum_ode"] + [x for k, v in {**base, **given}.items() for x in (k, v)]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before


def test_compare_tune_gives_every_kind_the_same_budget_on_disjoint_seeds(tmp_path, capsys):
    js = tmp_path / "c.json"
    status = main(["compare", "ex3_pendulum_ode", "--controller", "pd,lqr", "--tune", "2",
                   "--tune-seeds", "10:11", "--seeds", "0:2", "--duration", "0.5", "--jobs", "1",
                   "--resamples", "200", "--metric", "rmse", "--metrics", str(js)])
    assert status == 0
    assert "Tuned on an equal budget: 2 trials per kind" in capsys.readouterr().out
    doc = json.loads(js.read_text())
    assert [(t["controller"], t["trials"], t["train_seeds"]) for t in doc["tuned"]] == \
        [("pd", 2, [10]), ("lqr", 2, [10])]
    assert doc["pairs"][0]["pairs"] == 2
    assert main(["compare", "ex3_pendulum_ode", "--controller", "pd,lqr", "--tune", "2",
                 "--tune-seeds", "1:3", "--seeds", "0:2"]) == 2


def test_tuned_randomised_scenario_keeps_its_draws_and_reproduces_its_train_score(tmp_path,
                                                                                 executor):
    """On a [randomize] scenario each training seed is another machine: the tuned file
    keeps the [randomize] table, so rerunning it at the training seeds draws the same
    machines and gives back the reported score bit for bit."""
    from tspend.plants import randomize
    from tspend.sweep import sweep

    scn = _short("pendulum_mujoco_randomized", 0.5)
    r = tuning.tune(scn, "sliding_mode", trials=2, seeds=[3, 4], test_seeds=[5],
                    executor=executor, defaults=False)
    path = tmp_path / "tuned.toml"
    path.write_text(r.text)
    tuned = load_scenario(path)
    assert tuned.randomize == scn.randomize
    rows = sweep(tuned, seeds=[3, 4], controllers=["sliding_mode"], executor=executor)
    assert tuning.score(rows, "rmse") == r.train_score
    assert list(rows["drawn.m"]) == [randomize.draw(override(scn, **{"run.seed": s})).values["m"]
                                     for s in (3, 4)]
    assert rows["drawn.m"].nunique() == 2
