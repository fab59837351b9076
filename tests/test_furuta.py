"""The Furuta domain from the command line (issue 19): cross-check, lqr, inspect."""

from __future__ import annotations


def test_furuta_crosscheck_and_lqr_from_the_cli(tmp_path) -> None:
    """Issue 19's Furuta: open loop agrees to 1e-10 on every state; lqr holds it 5 s."""
    import json

    from tspend.cli.main import main

    cc = tmp_path / "cc.json"
    assert main(["crosscheck", "furuta_mujoco", "--duration", "1", "--metrics", str(cc),
                 "--no-record"]) == 0
    report = json.loads(cc.read_text())
    figures = {k: v for k, v in report.items() if k.startswith("open_loop_max_")}
    assert len(figures) == 5 and max(figures.values()) <= 1e-10, figures
    m = tmp_path / "m.json"
    assert main(["run", "furuta_mujoco", "--controller", "lqr", "--metrics", str(m),
                 "--no-record"]) == 0
    assert json.loads(m.read_text())["status"] == "completed"


def test_inspect_reports_the_furuta(capsys) -> None:
    from tspend.cli.main import main

    from pathlib import Path

    assert main(["inspect", str(Path(__file__).parents[1] / "models" / "furuta.xml")]) == 0
    out = capsys.readouterr().out
    assert "a furuta model" in out and "no departure from the furuta ODE" in out
