"""tools/check_docs.py and tools/check_claims.py (issue 42): what they extract, the exit
statuses they expect, the figures they compare; and the fair budget's range widening."""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

import numpy as np
import pytest

from cli_harness import ROOT

sys.path.insert(0, str(ROOT / "tools"))
import check_claims  # noqa: E402
import check_docs  # noqa: E402

DOC = '''# A document

<!-- check_docs: skip a viewer, for the test -->
```
rerun x.rrd
```

```
tspend run no_such_scenario            # exit 2
python -c "import sys; sys.exit(3)"
tspend: error: this line is output, not a command      [exit 3]
tspend run ex2_duffing \\
    --seed 3
  some output line
```

```py
this is an excerpt and is never run(
```

```python
print("hello")
```
'''


def test_extract_finds_commands_statuses_and_skips(tmp_path: Path) -> None:
    doc = tmp_path / "doc.md"
    doc.write_text(DOC)
    cmds = check_docs.extract(doc)
    shells = [c for c in cmds if c.kind == "shell"]
    assert [c.text.split()[0] for c in shells] == ["rerun", "tspend", "python", "tspend"]
    assert shells[0].skip == "a viewer, for the test"
    assert [c.expect for c in shells[1:]] == [2, 3, 0]     # comment, output line, default
    assert shells[3].text == "tspend run ex2_duffing \\\n    --seed 3"
    assert [c.text for c in cmds if c.kind == "python"] == ['print("hello")\n']
    assert not any("excerpt" in c.text for c in cmds)


def test_a_command_with_an_unexpected_status_fails(tmp_path: Path, capsys) -> None:
    good = tmp_path / "good.md"
    good.write_text('```\npython -c "import sys; sys.exit(3)"   # exit 3\n'
                    'tspend run no_such_scenario   # exit 2\n```\n')
    assert check_docs.main([str(good)]) == 0
    assert "ran 2 commands (2 with the expected exit status, 0 failed)" in capsys.readouterr().out
    bad = tmp_path / "bad.md"
    bad.write_text('```\npython -c "import sys; sys.exit(3)"\n```\n')
    assert check_docs.main([str(bad)]) == 1
    out = capsys.readouterr().out
    assert "FAIL" in out and "1 failed" in out


def test_a_misspelt_program_fails_where_output_would_have_hidden_it(tmp_path: Path,
                                                                     capsys) -> None:
    """A line of a command block is a known program, a comment, or output directly under
    a command; anything else, a misspelt program above all, fails without being run."""
    doc = tmp_path / "doc.md"
    doc.write_text('```\npython -c "print(1)"\n1\ntspnd run ex2_duffing --seed 3\n```\n\n'
                   '```\ntspnd run ex2_duffing\n```\n\n'
                   '```\npython -c "print(1)"\n\nstray text\n```\n\n'
                   '```\n$ tspend run ex2_duffing\ntspend: error: ...\n$ tspned list\n```\n\n'
                   '```\nscenario.toml ──► tspend/config/tables.py\n  hinge   0.001 / 0.0366\n```\n')
    problems = [(c.line, c.problem) for c in check_docs.extract(doc) if c.problem]
    assert [line for line, _ in problems] == [4, 8, 14, 20]
    assert "'tspnd' is not a program" in problems[0][1] and "'tspnd'" in problems[1][1]
    assert "neither a command nor output" in problems[2][1]
    assert "'tspned' after the prompt" in problems[3][1]
    assert check_docs.main([str(doc)]) == 1
    out = capsys.readouterr().out
    assert "FAIL" in out and "4 failed" in out and "ran 6 commands" in out


def test_inline_commands_are_read_and_reproduce_lines_run(tmp_path: Path, capsys) -> None:
    """Inline commands: a "Reproduce:" one runs; the others are read by tspend's own parser
    (or the script's source); a template is listed, not read."""
    doc = tmp_path / "doc.md"
    doc.write_text("Run `tspend run ex2_duffing --seed 3 --duration 1` or `tspend inspect`, "
                   "`tspend sweep --grid`, `tspend run SCENARIO --controller KIND`.\n\n"
                   "Reproduce: `python -c \"import sys; sys.exit(0)\"`.\n")
    cmds = check_docs.extract(doc)
    assert [c.kind for c in cmds] == ["inline"] * 4 + ["shell"]
    assert cmds[3].skip.startswith("a template")
    assert check_docs.main([str(doc)]) == 0, capsys.readouterr().out
    assert "ran 4 commands (4 with" in capsys.readouterr().out
    for broken, why in (("`tspend run ex2_duffing --sed 3`", "tspend does not accept it"),
                        ("`tspend sweep --gird`", "has no option --gird"),
                        ("`python benchmarks/no_such.py`", "no such script"),
                        ("`python benchmarks/seed_spread.py --no-such 2`", "has no option"),
                        ("`python -c \"print(1\"`", "does not compile")):
        doc.write_text(f"See {broken}.\n")
        cmd, = check_docs.extract(doc)
        assert why in check_docs.inline_problem(cmd.text)
        assert check_docs.main([str(doc)]) == 1
    doc.write_text('Reproduce: `python -c "import sys; sys.exit(4)"`.\n')
    assert check_docs.main([str(doc)]) == 1
    assert "exit 4 (expected 0" in capsys.readouterr().out


def test_a_command_needing_an_extra_runs_with_it_or_is_skipped_naming_it(
        tmp_path: Path, monkeypatch) -> None:
    from importlib import metadata

    doc = tmp_path / "doc.md"
    doc.write_text("```\npython benchmarks/mpc_speed.py\n```\n\n<!-- check_docs: needs "
                   "test -->\n```\npython -c 1\n```\n")
    # every distribution counts as installed unless named here as missing: the check must
    # not depend on which extras this environment has (CI installs [test] alone)
    installed = {"do-mpc": True, "pytest": True}

    def version(name: str) -> str:
        if not installed.get(name, True):
            raise metadata.PackageNotFoundError(name)
        return "1.0"

    monkeypatch.setattr(metadata, "version", version)
    bench, test = check_docs.extract(doc)
    assert (bench.needs, test.needs) == ("bench", "test")
    assert not test.skip and "needs the [bench]" not in bench.skip
    installed.update({"do-mpc": False, "pytest": False})
    bench, test = check_docs.extract(doc)
    assert bench.skip.startswith("needs the [bench] extra") and "do-mpc" in bench.skip
    assert test.skip.startswith("needs the [test] extra") and "pytest" in test.skip


def test_python_in_a_shell_block_is_this_environment(tmp_path: Path, capsys) -> None:
    """``python`` of a shell block has this environment's packages (a linked venv
    interpreter would start without them)."""
    doc = tmp_path / "doc.md"
    doc.write_text('```\npython -c "import numpy, mujoco"\n'
                   'python3 -c "import sys; sys.exit(0 if sys.prefix == %r else 5)"\n```\n'
                   % sys.prefix)
    assert check_docs.main([str(doc)]) == 0, capsys.readouterr().out


def test_a_benchmark_without_short_sizes_is_skipped_with_its_reason(tmp_path: Path) -> None:
    doc = tmp_path / "doc.md"
    doc.write_text("```\npython benchmarks/seed_spread.py\npython benchmarks/no_such.py\n"
                   "nice python benchmarks/safety_filter.py\n```\n")
    cmds = check_docs.extract(doc)
    takes_part = "short_mode" in (ROOT / "benchmarks" / "safety_filter.py").read_text()
    assert cmds[0].skip == "" and cmds[1].skip == ""     # a missing script fails when run
    assert bool(cmds[2].skip) is not takes_part
    assert all(c.skip for c in check_docs.extract(doc, short=True))


def test_a_full_only_block_runs_in_the_full_check_only(tmp_path: Path) -> None:
    doc = tmp_path / "doc.md"
    doc.write_text("<!-- check_docs: full-only needs what a benchmark makes -->\n"
                   "```\ntspend run ex2_duffing --seed 3\n```\n")
    full, = check_docs.extract(doc)
    short, = check_docs.extract(doc, short=True)
    assert full.skip == "" and full.full
    assert short.skip == "needs what a benchmark makes"


def test_short_mode_sizes(monkeypatch) -> None:
    import argparse

    sys.path.insert(0, str(ROOT / "benchmarks"))
    import short_mode

    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", default="0:20")
    ap.add_argument("--repeat", type=int, default=3)
    monkeypatch.setenv("TSPEND_BENCH_SHORT", "0")
    short_mode.short_defaults(ap, seeds="0:2")
    assert ap.parse_args([]).seeds == "0:20" and short_mode.sized(15, 2) == 15
    assert short_mode.judged() and str(short_mode.out_path("/x/y/r.json")) == "/x/y/r.json"
    monkeypatch.setenv("TSPEND_BENCH_SHORT", "1")
    short_mode.short_defaults(ap, seeds="0:2")
    assert ap.parse_args([]).seeds == "0:2" and ap.parse_args(["--seeds", "5:9"]).seeds == "5:9"
    assert short_mode.sized(15, 2) == 2 and not short_mode.judged()
    assert str(short_mode.out_path("/x/y/r.json")) == "r.json"
    with pytest.raises(ValueError, match="no option"):
        short_mode.short_defaults(ap, trials=2)


def test_a_real_document_runs_short(capsys) -> None:
    """The fast subset of the full check: one document of docs/ as a reader runs it."""
    assert check_docs.main(["--short", str(ROOT / "docs" / "third-party-models.md")]) == 0
    assert "0 failed" in capsys.readouterr().out


def test_shortened_keeps_the_documents_words() -> None:
    assert check_docs.shortened(["compare", "x", "--seeds", "5:20"]) == [
        "compare", "x", "--seeds", "5:7", "--duration", "0.3", "--jobs", "1", "--resamples", "100"]


@pytest.mark.parametrize("printed, value, ok", [
    ("0.0123", 0.01234, True), ("0.0123", 0.01236, False), ("3.5e+05", 3.54e5, True),
    ("3.5e+05", 3.56e5, False), ("1,234", 1234.4, True), ("−0.5", -0.5, True), ("12", 12.6, False)])
def test_a_figure_agrees_to_its_printed_digits(printed, value, ok) -> None:
    assert check_claims.agrees(printed, value) is ok


def test_marked_figures_are_checked_against_their_data(tmp_path: Path) -> None:
    (tmp_path / "d.json").write_text(json.dumps({"a": {"b": [1.0, 0.0313]}}))
    doc = tmp_path / "doc.md"
    doc.write_text("holds 0.0313 rad <!-- data: d.json a/b/1 --> and 3.13 % <!-- data: d.json a/b/1 x100 -->\n")
    assert check_claims.check_markers([doc], root=tmp_path) == (2, [])
    doc.write_text("holds 0.0314 rad <!-- data: d.json a/b/1 -->\n")
    n, problems = check_claims.check_markers([doc], root=tmp_path)
    assert n == 1 and "prints 0.0314" in problems[0]


def test_marked_figures_are_checked_against_raw_text_output(tmp_path: Path) -> None:
    (tmp_path / "r.txt").write_text("rk4  median 12.34 ms\neuler median 3.21 ms\ntotal 1,234 runs\n")
    doc = tmp_path / "doc.md"
    doc.write_text("RK4 takes 12.3 ms <!-- data: r.txt rk4\\s+median\\s+([\\d.]+) --> over "
                   "1,234 runs <!-- data: r.txt total\\s+([\\d,]+) -->\n")
    assert check_claims.check_markers([doc], root=tmp_path) == (2, [])
    doc.write_text("RK4 takes 12.4 ms <!-- data: r.txt rk4\\s+median\\s+([\\d.]+) -->\n")
    n, problems = check_claims.check_markers([doc], root=tmp_path)
    assert n == 1 and "prints 12.4" in problems[0]
    doc.write_text("3.2 ms <!-- data: r.txt median\\s+([\\d.]+) -->\n")  # two matches: ambiguous
    n, problems = check_claims.check_markers([doc], root=tmp_path)
    assert n == 0 and "matches 2 times" in problems[0]


def test_committed_claims_agree_with_their_data(capsys) -> None:
    """README's and docs/results.md's generated claims rebuilt from the kept runs."""
    assert check_claims.main([]) == 0, capsys.readouterr().out


# -- the fair budget ---------------------------------------------------------------------------
def test_edges_widen_and_budget_counts_parameters() -> None:
    from tspend.controllers.settings import Search
    from tspend.studies.tune import at_edge, budget_trials, position, widen

    log, lin = Search(0.2, 1000.0, True), Search(0.0, 1.0, False)
    assert position(log, 0.2) == 0.0 and position(log, 1000.0) == pytest.approx(1.0)
    assert at_edge({"p": log, "b": lin}, {"p": 990.0, "b": 0.5}) == {"p": "high"}
    assert at_edge({"p": log, "b": lin}, {"p": 5.0, "b": 0.01}) == {"b": "low"}
    assert widen(log, "high").high == pytest.approx(1000.0 * 5000.0)
    assert widen(log, "low").low == pytest.approx(0.2 / 5000.0)
    assert widen(lin, "low") is None and widen(lin, "high").high == 2.0
    assert budget_trials("second_type", 3) == 15 and budget_trials("pd", 3) == 3


def test_equal_budget_retunes_a_kind_whose_optimum_is_at_an_edge(monkeypatch) -> None:
    import pandas as pd

    import tspend.sweep
    from tspend.studies import tune as tune_mod

    calls = []

    def fake_tune(scn, kind, *, trials, space, **_):
        calls.append((kind, trials, dict(space)))
        high = space["bandwidth"].high
        x = high * 0.999 if high <= 1000.0 else 1500.0      # at the edge, then inside
        return tune_mod.TuneResult(kind=kind, metric="rmse", scenario=scn, base_name="s",
                                   values={"bandwidth": x}, drawn={"bandwidth": x},
                                   trials=trials, train_seeds=[1], test_seeds=[],
                                   train_score=1.0, test_score=None, space=dict(space),
                                   rounds=(trials,))

    class Scn:
        name = "s"

    monkeypatch.setattr(tune_mod, "tune", fake_tune)
    monkeypatch.setattr(tspend.sweep, "sweep",
                        lambda *a, seeds, **k: pd.DataFrame({"seed": seeds, "rmse": 1.0}))
    rows, tuned = tune_mod.equal_budget([Scn()], ["pd"], trials_per_parameter=3,
                                        train_seeds=[1], test_seeds=[2], executor=object(),
                                        widen_rounds=2)
    r = tuned[("s", "pd")]
    assert [c[1] for c in calls] == [3, 3] and r.rounds == (3, 3)
    assert calls[1][2]["bandwidth"].high == pytest.approx(1000.0 * 5000.0)
    assert tune_mod.position(r.space["bandwidth"], r.drawn["bandwidth"]) < 0.95
    with pytest.raises(Exception, match="one of them"):
        tune_mod.equal_budget([Scn()], ["pd"], trials=3, trials_per_parameter=3,
                              train_seeds=[1], test_seeds=[2], executor=object())


def test_the_furuta_linearisation_data_is_what_todays_code_computes() -> None:
    """docs/furuta.md's A, B, eigenvalues and LQR gain are marked against this JSON; it
    must still be what benchmarks/furuta_linearization.py computes (control.lqr is the
    independent Riccati solve)."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    import furuta_linearization as fl

    kept = json.loads(fl.OUT.read_text())
    now = json.loads(json.dumps(fl.measure()))
    assert kept.keys() == now.keys()
    for key in ("A", "B", "eig_upright", "eig_hanging", "K"):
        np.testing.assert_allclose(np.array(now[key]), np.array(kept[key]), rtol=1e-9, atol=1e-12,
                                   err_msg=key)


# -- every figure is checked or listed (issue 56) ----------------------------------------------
#: what a reader sees of a line: code spans, HTML comments and link targets are not figures
_HIDDEN = re.compile(r"`[^`]*`|<!--.*?-->|\]\([^)]*\)|https?://\S+")


def _reader_figures(text: str) -> list[tuple[int, int, int]]:
    """(line, start, end) of every run of digits a reader sees in a table row or a sentence:
    outside fenced blocks, headings, code spans, comments, link targets and names."""
    found, fenced, offset = [], False, 0
    for number, line in enumerate(text.splitlines(keepends=True), 1):
        stripped = line.strip()
        if stripped.startswith("```"):
            fenced = not fenced
        elif not fenced and not stripped.startswith("#") and "<!--" not in line[:4]:
            hidden = [m.span() for m in _HIDDEN.finditer(line)]
            for m in re.finditer(r"(?<![A-Za-z_\d])\d+", line):   # not in a name (RK4)
                if not any(a <= m.start() < b for a, b in hidden) and \
                        not re.match(r"\s*\d+\.\s", line[:m.end() + 2]):
                    found.append((number, offset + m.start(), offset + m.end()))
        offset += len(line)
    return found


def _scratch_copy(tmp: Path) -> Path:
    """README.md and docs/*.md copied under ``tmp``, everything else linked."""
    (tmp / "docs").mkdir()
    for entry in ROOT.iterdir():
        if entry.name not in ("docs", "README.md", ".git", ".venv"):
            (tmp / entry.name).symlink_to(entry)
    for entry in (ROOT / "docs").iterdir():
        if entry.suffix != ".md":
            (tmp / "docs" / entry.name).symlink_to(entry)
    for doc in [ROOT / "README.md", *(ROOT / "docs").glob("*.md")]:
        (tmp / doc.relative_to(ROOT)).write_text(doc.read_text(encoding="utf-8"))
    return tmp


def test_changing_any_figure_fails_a_check_or_shows_on_the_unchecked_list(tmp_path: Path) -> None:
    """In a scratch copy, one digit of a figure a reader sees is changed at a time (60 drawn
    over every document): the marked-figure check or a generated section's rebuild fails,
    or the changed figure is listed as unchecked at its line."""
    root = _scratch_copy(tmp_path)
    docs = [root / "README.md", *sorted((root / "docs").glob("*.md"))]
    where = [(doc, *f) for doc in docs for f in _reader_figures(doc.read_text(encoding="utf-8"))]
    rng = np.random.default_rng(56)
    for k in rng.choice(len(where), size=60, replace=False):
        doc, line, start, end = where[k]
        text = doc.read_text(encoding="utf-8")
        digits = text[start:end]
        changed = digits[:-1] + str((int(digits[-1]) + 1) % 10)
        doc.write_text(text[:start] + changed + text[end:])
        try:
            problems = check_claims.check_markers([doc], root=root)[1]
            problems += check_claims.check_sections(root=root)[1]
            listed = [figure for n, figure in check_claims.unchecked_figures(doc, doc.read_text(),
                                                                              root=root)
                      if n == line]
            assert problems or any(changed in figure.lstrip("-−") for figure in listed), \
                f"{doc.relative_to(root)}:{line}: {digits} -> {changed} went unnoticed"
        finally:
            doc.write_text(text)


def test_the_unchecked_figures_are_counted_against_a_ceiling(tmp_path: Path) -> None:
    doc = tmp_path / "d.md"
    doc.write_text("| kind | rmse |\n|---|---|\n| pd | 0.0123 |\n\nA 7x speed-up over 0-19 "
                   "seeds, `tspend run x --seed 4` and 12.4 <!-- data: r.json a -->.\n\n"
                   "```\nout 3.5\n```\n")
    (tmp_path / "r.json").write_text('{"a": 12.4}')
    listing, problems, count = check_claims.check_unchecked([doc], root=tmp_path, at_most=4)
    assert count == 4 and problems == []
    assert listing == ["d.md:3: 0.0123", "d.md:5: 7, 0, 19"]
    assert check_claims.check_unchecked([doc], root=tmp_path, at_most=3)[1]


# -- an equal search: a space-filling start, then the same guided search (issue 56) ------------
def test_the_space_filling_start_covers_every_range_in_each_setting() -> None:
    from tspend.controllers.settings import Search
    from tspend.studies.tune import space_filling_start

    space = {"bandwidth": Search(0.2, 1000.0, True), "eta": Search(0.0, 2.0, False),
             "gamma": Search(1e-3, 10.0, True), "q": Search(0.1, 100.0, True),
             "phi": Search(0.0, 0.5, False)}
    points = space_filling_start(space, 8, seed=0)
    assert len(points) == 8
    for key, s in space.items():
        # the position in the range, computed here on its own (log scale for a log range)
        at = np.array([(np.log(p[key] / s.low) / np.log(s.high / s.low)) if s.log
                       else (p[key] - s.low) / (s.high - s.low) for p in points])
        assert np.all((at >= 0) & (at <= 1))
        assert sorted(np.floor(at * 8).astype(int)) == list(range(8)), key   # one per eighth
    assert space_filling_start(space, 8, seed=1) != points        # scrambled by the seed


def test_tune_starts_from_the_space_filling_points_then_tpe_guides(monkeypatch) -> None:
    """The first trials are the Sobol points, in order; the trials after them are TPE's,
    drawn near the best start point (a score with one minimum at 3 rad/s)."""
    pytest.importorskip("optuna")
    import tspend.scenario
    import tspend.sweep
    from tspend.controllers.settings import Search
    from tspend.scenario import load_scenario
    from tspend.studies import tune as tune_mod

    tried: list[float] = []

    def remember(scenario, **changes):
        tried.append(next(v for k, v in changes.items() if k.endswith("bandwidth")))
        return scenario

    monkeypatch.setattr(tspend.scenario, "override", remember)
    monkeypatch.setattr(tspend.sweep, "build_once", lambda plan: None)
    monkeypatch.setattr(tune_mod, "_sweep_score",
                        lambda scn, *a: abs(np.log(tried[-1] / 3.0)))
    space = {"bandwidth": Search(0.2, 1000.0, True)}
    r = tune_mod.tune(load_scenario("ex3_pendulum_ode"), "pd", trials=16, seeds=[1],
                      executor=object(), defaults=False, space=space, start_trials=8)
    start = [p["bandwidth"] for p in tune_mod.space_filling_start(space, 8, 0)]
    np.testing.assert_allclose(tried[:8], start, rtol=1e-12)
    assert min(tune_mod.position(space["bandwidth"], x) for x in tried[:8]) < 0.125
    guided = tried[8:16]
    best_start = min(start, key=lambda x: abs(np.log(x / 3.0)))
    assert np.median(np.abs(np.log(np.array(guided) / 3.0))) < abs(np.log(start[0] / 3.0))
    assert abs(np.log(r.drawn["bandwidth"] / 3.0)) <= abs(np.log(best_start / 3.0))
    assert tune_mod.budget_trials("pd", 8, start_trials=8) == 16
    assert tune_mod.budget_trials("second_type", 8, start_trials=8) == 48
    with pytest.raises(Exception, match="start_trials"):
        tune_mod.tune(load_scenario("ex3_pendulum_ode"), "pd", trials=4, seeds=[1],
                      executor=object(), space=space, start_trials=5)
