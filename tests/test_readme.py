"""The README is a short front page whose every command works.

Each ``tspend`` line of the README and of docs/reference/cli.md is checked against the
command's parser; the README's are then run, in order, in a scratch directory, with
short durations and few seeds (the only edits: ``--duration``, ``--seeds``, ``--jobs``,
``--resamples``), and its Python blocks are executed as they are.  The quick-start
commands are the two the project promises, and ``.ci/run`` runs the second.
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from cli_harness import ROOT
from tspend.cli.main import build_parser, main

README = ROOT / "README.md"
QUICK_START = (
    "python3 -m venv .venv && .venv/bin/pip install . && .venv/bin/tspend run",
    "python3 -m venv .venv && .venv/bin/pip install -q -e '.[test]' && "
    ".venv/bin/python -m pytest -q",
)
#: how each command is shortened: tools/check_docs.py's rule, the one both checks use
sys.path.insert(0, str(ROOT / "tools"))
from check_docs import SHORT  # noqa: E402


def blocks(path: Path, language: str = "") -> list[str]:
    """The fenced code blocks of ``path`` in ``language`` ("" = none given)."""
    text = path.read_text()
    return re.findall(rf"^```{language}\n(.*?)^```", text, flags=re.S | re.M)


def tspend_lines(path: Path) -> list[list[str]]:
    """Every ``tspend ...`` command of the plain code blocks, as argv (comments dropped; a
    ``> FILE`` redirection kept at the end, :func:`redirected` takes it off).  A line
    ``tspend A && tspend B`` gives both commands."""
    out = []
    for block in blocks(path):
        for line in block.splitlines():
            if line.startswith("tspend "):
                out.extend(chained(shlex.split(line, comments=True)))
    return out


def chained(words: list[str]) -> list[list[str]]:
    """The argv of each ``tspend`` command in ``words`` split at ``&&``."""
    commands, current = [], []
    for word in words + ["&&"]:
        if word != "&&":
            current.append(word)
            continue
        if current and current[0] == "tspend":
            commands.append(current[1:])
        current = []
    return commands


def redirected(argv: list[str]) -> tuple[list[str], str | None]:
    """``(argv, FILE)`` of a line ending ``> FILE``; ``(argv, None)`` otherwise."""
    if ">" in argv:
        i = argv.index(">")
        return argv[:i], argv[i + 1]
    return argv, None


def test_readme_is_short_and_keeps_the_quick_start() -> None:
    text = README.read_text()
    assert len(text.splitlines()) <= 250
    assert [b.strip() for b in blocks(README)[:2]] == list(QUICK_START)
    assert QUICK_START[1] in (ROOT / ".ci" / "run").read_text()


def test_ci_runs_the_tests_from_new_empty_caches(tmp_path) -> None:
    """.ci/run points every cache folder (numba's, tspend's, JAX's and the other
    XDG ones, matplotlib's, Python's byte code) at a new empty folder before the README's
    test command, so a test that passes only on a warm cache fails in CI (issue 51)."""
    source = "\n".join(p.read_text() for p in (ROOT / "tspend").rglob("*.py"))
    read = set(re.findall(r'environ\.get\("([A-Z_]*CACHE_(?:DIR|HOME))"', source))
    wanted = read | {"NUMBA_CACHE_DIR", "XDG_CACHE_HOME", "MPLCONFIGDIR", "PYTHONPYCACHEPREFIX"}
    script = (ROOT / ".ci" / "run").read_text()
    probe = "; ".join(f'echo "{v}=${{{v}:-}}"; '
                      f'{{ ls -A "${{{v}:-/nonexistent}}" 2>/dev/null || true; }}'
                      for v in sorted(wanted))
    (tmp_path / ".ci").mkdir()
    (tmp_path / ".ci" / "run").write_text(script.replace(QUICK_START[1], probe))
    out = subprocess.run(["bash", str(tmp_path / ".ci" / "run")], capture_output=True,
                         text=True, check=True, timeout=60).stdout.splitlines()
    folders = dict(line.split("=", 1) for line in out if "=" in line)
    assert set(folders) == wanted and all(folders.values()), out
    assert len(out) == len(wanted)  # nothing listed: every folder new and empty
    assert not any(Path(f).exists() for f in folders.values())  # and removed after


def test_every_extra_and_example_is_reachable_from_the_readme() -> None:
    """Issue 51, item 7: each extra of pyproject.toml is named in the README (``[name]``),
    each example file too, and the README says how to find them in an installed wheel."""
    import tomllib

    text = README.read_text()
    extras = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]
    assert [e for e in extras if f"[{e}]" not in text] == []
    assert [p.name for p in (ROOT / "examples").glob("*.py") if f"examples/{p.name}" not in text] == []
    assert "tspend list --files" in text


def test_no_document_uses_a_deprecated_spelling() -> None:
    """Issue 51, item 6: every ``tspend`` command of README.md and docs/*.md, in a block or
    in running text, parsed by tspend's parser, uses no deprecated option (``crosscheck
    --json``): a reader copies what the documents show."""
    from tspend.cli.common import UsageError

    parser = build_parser()
    used = []
    for path in [README, *sorted((ROOT / "docs").rglob("*.md"))]:
        text = path.read_text()
        commands = re.findall(r"`(tspend [^`\n]+)`", text)
        commands += [line for block in blocks(path) for line in block.splitlines()
                     if line.startswith("tspend ")]
        for command in commands:
            try:
                argv = shlex.split(command.split("#")[0].split(" > ")[0].split(" | ")[0])[1:]
                args = parser.parse_args(argv)
            except (UsageError, ValueError, SystemExit):
                continue  # a placeholder (<machine>) or an excerpt: not this test's subject
            used += [f"{path.name}: {command}: {n}" for n in getattr(args, "deprecations", [])]
    assert used == []


def test_readme_links_and_pictures_exist() -> None:
    targets = re.findall(r"\]\(([^)#]+)\)", README.read_text())
    assert any(t.startswith("docs/img/") for t in targets)
    assert any(t.startswith("docs/results/figures/") for t in targets)
    missing = [t for t in targets if not t.startswith("http") and not (ROOT / t).exists()]
    assert not missing, missing


@pytest.mark.parametrize("doc", ["README.md", "docs/reference/cli.md"])
def test_every_command_parses(doc: str) -> None:
    lines = tspend_lines(ROOT / doc)
    assert len(lines) >= 8
    parser = build_parser()
    for argv in lines:
        parser.parse_args(redirected(argv)[0])  # a bad option raises UsageError


def shortened(argv: list[str]) -> list[str]:
    argv = ["0:2" if prev == "--seeds" else a for prev, a in zip([""] + argv, argv)]
    return argv + SHORT.get(argv[0], [])


def test_readme_commands_run(tmp_path: Path, monkeypatch, capsys) -> None:
    for name in ("examples", "models"):
        os.symlink(ROOT / name, tmp_path / name)
    monkeypatch.chdir(tmp_path)
    for argv in tspend_lines(README):
        argv, into = redirected(argv)
        status = main(shortened(argv) if into is None else argv)
        captured = capsys.readouterr()
        assert status == 0, (argv, captured.err)
        if into is not None:
            (tmp_path / into).write_text(captured.out)
    assert (tmp_path / "m.json").exists() and (tmp_path / "duffing.csv").exists()


def test_every_tour_line_runs_after_the_first_command_or_names_its_extra() -> None:
    """The first command installs the core dependencies only: a tour line that needs an
    optional extra says which in a comment (``# [tune]``), as its error line would."""
    from tspend.cli.extras import EXTRAS, needed

    parser = build_parser()
    checked = 0
    for block in blocks(README):
        for line in block.splitlines():
            if not line.startswith("tspend "):
                continue
            args = parser.parse_args(redirected(shlex.split(line, comments=True)[1:])[0])
            for module, _ in needed(args):
                extra = EXTRAS[module][1]
                checked += extra is not None
                assert extra is None or f"[{extra}]" in line, (line, extra)
    assert checked >= 1  # the tune line at least


def test_readme_python_runs(tmp_path: Path, monkeypatch) -> None:
    monkeypatch.chdir(tmp_path)
    # as a user runs it: a script of its own (a sweep's worker processes re-import the
    # script, which an exec() inside pytest would not show)
    for i, block in enumerate(blocks(README, "python")):
        script = tmp_path / f"readme_{i}.py"
        script.write_text(block)
        env = {**os.environ, "PYTHONPATH": str(ROOT), "MPLBACKEND": "Agg"}
        done = subprocess.run([sys.executable, str(script)], cwd=tmp_path, env=env,
                              capture_output=True, text=True, timeout=300)
        assert done.returncode == 0, done.stderr[-2000:]


#: walk-throughs in docs/ whose commands and ```python blocks are run like the README's
#: (excerpts of tspend's own source are fenced ```py and only read)
WALK_THROUGHS = ("docs/writing-a-plant.md",)


@pytest.mark.parametrize("doc", WALK_THROUGHS)
def test_walk_through_commands_and_python_run(doc: str, tmp_path: Path, monkeypatch,
                                              capsys) -> None:
    pytest.importorskip("control")
    path = ROOT / doc
    os.symlink(ROOT / "models", tmp_path / "models")
    monkeypatch.chdir(tmp_path)
    lines = tspend_lines(path)
    assert lines
    for argv in lines:
        status = main(shortened(argv))
        assert status == 0, (argv, capsys.readouterr().err)
    for block in blocks(path, "python"):
        exec(compile(block, doc, "exec"), {"__name__": "walk_through"})  # noqa: S102
