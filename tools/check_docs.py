"""Run every shell and Python block of README.md and docs/*.md, and check its exit status.

    python tools/check_docs.py                       # every command; benchmarks at short sizes
    python tools/check_docs.py --short               # runs shortened, no benchmarks (tests)
    python tools/check_docs.py --short docs/identify.md README.md
    python tools/check_docs.py --list                # what would run and what is skipped, why
    python tools/check_docs.py --wheel ENV/bin/python  # first blocks, from the wheel

Which blocks: every fenced block of the documents named (default README.md and
docs/*.md) whose language is empty, ``sh``, ``bash``, ``shell``, ``console`` (shell) or
``python`` (a script run as a user runs it). ``py`` blocks are excerpts of tspend's own
source, ``toml`` blocks scenario text: read, never run. In a shell block a line is a
command when it starts with a program a reader types (``tspend``, ``python``,
``python3``, ``nice``, ``rerun``, ``pip``, ``cd``, ...); the other lines are the output a
reader sees, never run. A command continues on the next line after a trailing ``\\``.
Output sits directly under its command (no blank line between); in a block with commands
any other line is an error, and so is, in any shell block, a line shaped like a command
(a word then options or paths, a word close to a known program, a program on PATH) whose
program is not known: a misspelt ``tspnd run ...`` fails rather than pass as output. A
``$ `` prompt marks a transcript: shown, not run, its program checked.

Inline commands (in backticks in the prose, starting with ``tspend``, ``python`` or
``nice python``): on a line that says "Reproduce" they run as a fenced command does (a
benchmark's ``--seeds`` dropped: it takes its short seeds); the
others are read, not run: tspend's own parser must accept the words, a script must exist
and name each option given, ``python -c`` code must compile. One with placeholders
(``SCENARIO``, ``KIND``, ``...``, ``<machine>``) is a template: listed as skipped.

A command that needs an optional extra of pyproject.toml (:data:`EXTRA_RULES`, or a
marker ``<!-- check_docs: needs EXTRA -->`` before its block) runs when the extra's
distributions are installed and is otherwise skipped with the extra named, so the check
passes from the README's test environment (``pip install -e '.[test]'``).

Each document runs in its own scratch folder, its blocks in order (a later command may use
what an earlier one wrote), with ``models``, ``examples``, ``scenarios``, ``benchmarks``
and ``tools`` linked from the repository. ``tspend`` is ``python -m tspend.cli`` of this
tree, ``python``/``python3`` this interpreter. After every document the repository's
``git status`` must be what it was: no documented command writes into the repository.

The exit status a command must give: 0, unless the text says otherwise, in one of three
ways: a comment on the command line ``# exit N``, an output line under it ending in
``[exit N]`` (the style of docs/identify.md), or a marker comment before the block
``<!-- check_docs: exit N -->`` (every command of that block). A block that cannot run
here is skipped only with a stated reason: a marker ``<!-- check_docs: skip REASON -->``
before it, or a rule of :data:`SKIP_RULES` (a viewer, an install), each printed. A block
whose later commands need its runs whole (an identification needs its 16 s of data) is
marked ``<!-- check_docs: full -->``: not shortened under ``--short``. A block that runs only in
the full check (it needs what a benchmark script, skipped under ``--short``, made) is marked
``<!-- check_docs: full-only REASON -->``: skipped under ``--short`` with REASON.

The two modes:

* full (no option): every command runs (a benchmark script that does not take part in
  benchmarks/short_mode.py is skipped, said so). ``tspend`` commands and Python blocks run as the
  document writes them (its durations, seeds, trials). A benchmark script
  (``python benchmarks/...``) runs end to end with ``TSPEND_BENCH_SHORT=1``: each script
  takes short sizes (fewer seeds, blocks, runs; benchmarks/short_mode.py) and writes what
  it writes into the scratch folder, so its numbers are a smoke run, not the figures the
  documents quote. The figures are checked against their data by tools/check_claims.py;
  ``tools/check_claims.py --recompute N`` re-derives the fair comparison's runs at full
  size on today's code; a benchmark run by hand (no variable) gives full sizes.
* ``--short``: runs are shortened the way tests/test_readme.py does it (``--duration``,
  ``--seeds`` of two, ``--jobs 1``, ``--resamples``, ``--trials 2``; the benchmark
  scripts are skipped, named); every other word of the command is the document's. Python
  blocks run as written. This is the fast subset the test suite runs.

The full check runs everything with the test and bench extras (pip install -e
'.[test,bench]': gymnasium's MuJoCo envs, simpful, do-mpc for the benchmarks' peers);
with the test extra alone the bench commands are skipped, named.

Exit 0 when every command ran with its expected status and the repository is as it was;
1 otherwise. The last line says how many commands ran, how many failed, how many were
skipped and why, and the wall time.
"""

from __future__ import annotations

import argparse
import contextlib
import difflib
import functools
import io
import os
import re
import shlex
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SHELL_LANGS = ("", "sh", "bash", "shell", "console")
#: programs a command line starts with (anything else in a shell block is output)
PROGRAMS = ("tspend", "python", "python3", "nice", "rerun", "pip", "cd", "source", "mkdir",
            "cp", "mv", "cat", "ls", "export", "PYTHONPATH=", "TSPEND_", ".venv/", "sudo",
            "git", "curl", "wget", "jupyter", "./", "for ", "echo", "timeout", "time",
            "apt-get", "cc ", "gcc ")
#: (regular expression on a command, why it is not run here)
SKIP_RULES = (
    (r"^rerun\b|\brerun\s+\S+\.rrd", "opens Rerun's viewer (a window or a web server)"),
    (r"(^|&&\s*)python3? -m venv|pip install|^sudo |apt-get",
     "installs software (a fresh environment and the network; the checked tree is already "
     "installed)"),
    (r"--serve-web|--spawn|--connect", "needs a running viewer"),
    (r"^(curl|wget|git clone)\b", "needs the network"),
    (r"^source ", "activates a virtual environment (the checked tree is already on the path)"),
    (r"--dask\b", "needs a Dask scheduler"),
    (r"tools/screenshots\.py", "needs Chromium and a display"),
    (r"tools/check_docs\.py", "this checker itself"),
    (r"tools/check_claims\.py( .*)?--recompute", "re-runs benchmarks (minutes to hours)"),
)
#: (regular expression on a command, the extra of pyproject.toml it needs): run when the
#: extra's packages are installed, else skipped with the extra named
EXTRA_RULES = (
    (r"benchmarks/(mpc_speed|env_speed)\.py", "bench"),
)
#: skipped under --short only: run in the full check
SHORT_SKIP_RULES = (
    (r"^(nice )?python3? benchmarks/", "a benchmark script (the full check runs it, at "
                                        "short sizes)"),
)
#: per tspend subcommand, options appended under --short (the last of a repeated one wins)
SHORT = {
    "run": ["--duration", "0.3"],
    "crosscheck": ["--duration", "0.3", "--open-loop-duration", "0.6"],
    "sweep": ["--duration", "0.3", "--jobs", "1"],
    "compare": ["--duration", "0.3", "--jobs", "1", "--resamples", "100"],
    "figures": ["--duration", "0.3"],
    "tune": ["--duration", "0.3", "--trials", "2"],
}
EXIT_COMMENT = re.compile(r"#\s*exit\s+(\d+)\s*$")
EXIT_OUTPUT = re.compile(r"\[exit\s+(\d+)\]\s*$")
MARKER = re.compile(r"<!--\s*check_docs:\s*(skip|exit|full-only|full|needs)\s*(.*?)\s*-->")
#: a command in backticks in the prose: ``tspend ...``, ``python ...``, ``nice python ...``
INLINE = re.compile(r"`((?:nice\s+)?(?:tspend|python3?)\s[^`]*)`")
#: a placeholder the reader fills in (SCENARIO, KIND, FILE.csv, <machine>, [--opt], A:B, ...)
PLACEHOLDER = re.compile(r"\.\.\.|[<>\[\]]|(?<![\w.=/-])[A-Z][A-Z0-9_]+\b")
#: an argument that names a file: a path with a folder, or a name with a file's suffix
PATHLIKE = re.compile(r"^[\w.-]+/[\w./-]+$|^[\w.-]+\.(py|toml|csv|rrd|xml|json|parquet|onnx|txt)$")


@dataclass
class Command:
    doc: str
    line: int                 # 1-based line of the document where it starts
    text: str
    kind: str                 # "shell" or "python"
    expect: int = 0
    skip: str = ""            # the reason, when not run
    full: bool = False        # run at full length under --short too (marker "full")
    problem: str = ""         # why the line is wrong as written (never run)
    needs: str = ""           # the extra of pyproject.toml it needs (marker "needs")


@dataclass
class Outcome:
    command: Command
    status: int | None
    seconds: float
    tail: str = ""
    ok: bool = field(default=False)


def _is_command(line: str) -> bool:
    s = line.strip()
    if not s or s.startswith("#"):
        return False
    word = s.split()[0]
    return any(word == p.strip() if p[-1].isalnum() else s.startswith(p) for p in PROGRAMS)


def extract(path: Path, short: bool = False) -> list[Command]:
    """The commands of one document, fenced and inline, in the document's order, with their
    expected status, skip reason or problem."""
    lines = path.read_text(encoding="utf-8").splitlines()
    doc = path.relative_to(ROOT).as_posix() if path.is_relative_to(ROOT) else str(path)
    out: list[Command] = []
    prose: list[tuple[int, str]] = []
    i = 0
    while i < len(lines):
        m = re.match(r"^(\s*)```\s*([A-Za-z0-9_+-]*)\s*$", lines[i])
        if not m:
            prose.append((i + 1, lines[i]))
            i += 1
            continue
        indent, lang = m.group(1), m.group(2).lower()
        start = i + 1
        j = start
        while j < len(lines) and not re.match(rf"^{indent}```\s*$", lines[j]):
            j += 1
        body = [ln[len(indent):] if ln.startswith(indent) else ln for ln in lines[start:j]]
        marker = _marker_before(lines, i)
        i = j + 1
        if lang == "python":
            cmd = Command(doc, start + 1, "\n".join(body) + "\n", "python")
            _apply_marker(cmd, marker, short)
            out.append(cmd)
        elif lang in SHELL_LANGS:
            out += _shell_block(doc, start, body, marker, short)
    out += _inline_commands(doc, prose, short)
    return sorted(out, key=lambda c: c.line)


def _shell_block(doc: str, start: int, body: list[str], marker, short: bool) -> list[Command]:
    """The commands of one shell block; a line that is neither a command, a comment, nor
    output directly under a command (no blank line between) is a problem."""
    out: list[Command] = []
    has_commands = any(map(_is_command, body))
    k, under = 0, False
    while k < len(body):
        if not _is_command(body[k]):
            text = body[k].strip()
            under = under and bool(text)
            problem = _not_a_command(text, under, has_commands) if text and \
                not text.startswith("#") else ""
            if problem:
                out.append(Command(doc, start + k + 1, text, "shell", problem=problem))
            k += 1
            continue
        first = k
        parts = [body[k].rstrip()]
        while parts[-1].endswith("\\") and k + 1 < len(body):
            k += 1
            parts.append(body[k].rstrip())
        k += 1
        under = True
        cmd = Command(doc, start + first + 1, "\n".join(parts).strip(), "shell")
        _apply_marker(cmd, marker, short)
        e = EXIT_COMMENT.search(parts[-1])
        if e:
            cmd.expect = int(e.group(1))
        # the output lines under it, up to the next command, may state its status
        n = k
        while n < len(body) and not _is_command(body[n]):
            e = EXIT_OUTPUT.search(body[n])
            if e:
                cmd.expect = int(e.group(1))
            n += 1
        _skip_rules(cmd, short)
        out.append(cmd)
    return out


def _skip_rules(cmd: Command, short: bool) -> None:
    """The reason not to run ``cmd`` here, from :data:`SKIP_RULES`, its extra, its size."""
    for rule, why in SKIP_RULES + (SHORT_SKIP_RULES if short else ()):
        if not cmd.skip and re.search(rule, cmd.text, flags=re.M):
            cmd.skip = why
    for rule, extra in EXTRA_RULES:
        if re.search(rule, cmd.text):
            cmd.needs = cmd.needs or extra
    if not cmd.skip and cmd.needs:
        missing = missing_from_extra(cmd.needs)
        if missing:
            cmd.skip = (f"needs the [{cmd.needs}] extra (pip install -e '.[{cmd.needs}]'), "
                        f"not installed: {', '.join(missing)}")
    if not cmd.skip:
        cmd.skip = _unsized_benchmark(cmd.text)


def _not_a_command(text: str, under: bool, has_commands: bool) -> str:
    """Why a line of a shell block that is not a command is wrong, or "" (it is output)."""
    names = [p.strip() for p in PROGRAMS if p.strip().replace("-", "").isalnum()]
    m = re.match(r"([a-z][\w+-]*)(?:\s+(.*))?$", text)
    if text.startswith("$ "):    # a transcript's command: its program must be known
        shown = text[2:].strip()
        return "" if _is_command(shown) else \
            f"'{shown.split()[0] if shown else ''}' after the prompt is not a known program"
    if m:
        word, rest = m.group(1), (m.group(2) or "").split()
        if difflib.get_close_matches(word, names, n=1, cutoff=0.75) or shutil.which(word) \
                or any(a.startswith("--") or PATHLIKE.match(a) for a in rest):
            return (f"'{word}' is not a program this checker knows ({', '.join(names[:6])}, "
                    f"...): a misspelling, or a program to add to PROGRAMS")
    if has_commands and not under:
        return "neither a command nor output directly under one (no blank line between)"
    return ""


def _inline_commands(doc: str, prose: list[tuple[int, str]], short: bool) -> list[Command]:
    """The commands in backticks of the prose: those on a "Reproduce:" line run as a fenced
    command does; the others are read by their program (see :func:`inline_problem`)."""
    out = []
    for line, text in prose:
        for m in INLINE.finditer(text):
            command = m.group(1).strip()
            if "reproduce" in text[:m.start()].lower():
                # a benchmark takes its short seeds (benchmarks/short_mode.py), not the
                # full set the sentence reproduces
                cmd = Command(doc, line, re.sub(r"\s--seeds[ =]\S+", "", command)
                              if "benchmarks/" in command else command, "shell")
                _skip_rules(cmd, short)
            else:
                cmd = Command(doc, line, command, "inline")
                if PLACEHOLDER.search(command):
                    cmd.skip = "a template (placeholders the reader fills in): listed, not read"
            out.append(cmd)
    return out


@functools.cache
def _tspend_parser():
    sys.path.insert(0, str(ROOT))
    from tspend.cli.main import build_parser

    return build_parser()


def inline_problem(text: str) -> str:
    """What is wrong with an inline command, read without running it: tspend's own parser
    must accept its words; a script must exist and name each of its options; ``python -c``
    code must compile. "" when nothing is."""
    try:
        argv = shlex.split(text.split(" | ")[0])
    except ValueError as exc:
        return f"cannot be split into words ({exc})"
    argv = argv[1:] if argv[0] == "nice" else argv
    if argv[0] == "tspend":
        subs = _subcommands()
        if len(argv) == 2 and argv[1] in subs:
            return ""          # the name of a command, not a call
        if len(argv) == 3 and argv[1] in subs and argv[2].startswith("--"):
            # the name of an option
            known = argv[2] in subs[argv[1]]._option_string_actions
            return "" if known else f"tspend {argv[1]} has no option {argv[2]}"
        err = io.StringIO()
        try:
            with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
                _tspend_parser().parse_args(argv[1:])
        except SystemExit as exc:
            if exc.code:
                return f"tspend does not accept it: {err.getvalue().strip()[-200:]}"
        except Exception as exc:   # tspend's parser raises its own usage error
            return f"tspend does not accept it: {exc}"
        return ""
    if len(argv) > 2 and argv[1] == "-c":
        try:
            compile(argv[2], "<inline>", "exec")
        except SyntaxError as exc:
            return f"its code does not compile ({exc.msg})"
        return ""
    script = ROOT / argv[1] if len(argv) > 1 else None
    if script is None or script.suffix != ".py" or not script.is_file():
        return f"no such script: {argv[1] if len(argv) > 1 else '(none)'}"
    source = script.read_text(encoding="utf-8")
    unknown = [a.split("=")[0] for a in argv[2:] if a.startswith("--")
               and f'"{a.split("=")[0]}"' not in source]
    return f"{argv[1]} has no option {', '.join(unknown)}" if unknown else ""


def _subcommands() -> dict:
    """tspend's subcommands: name -> its parser."""
    return next(a for a in _tspend_parser()._actions if a.dest == "command").choices


def missing_from_extra(extra: str) -> list[str]:
    """The distributions of pyproject.toml's optional ``extra`` that are not installed."""
    import tomllib
    from importlib.metadata import PackageNotFoundError, version

    extras = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"][
        "optional-dependencies"]
    missing = []
    for requirement in extras.get(extra, []):
        name = re.match(r"[A-Za-z0-9_.-]+", requirement).group(0)
        try:
            version(name)
        except PackageNotFoundError:
            missing.append(name)
    return missing


def _unsized_benchmark(text: str) -> str:
    """The reason to skip a benchmark script that takes no short sizes, else "".

    The full check runs a benchmark end to end only when the script takes part in
    benchmarks/short_mode.py (it names the module): one that does not would run at its
    full size (hours) and may write its results into benchmarks/results/ of the
    repository."""
    m = re.match(r"^(?:nice\s+)?python3?\s+(benchmarks/\S+\.py)", text)
    if not m:
        return ""
    script = ROOT / m.group(1)
    if script.is_file() and "short_mode" not in script.read_text(encoding="utf-8"):
        return ("a benchmark script that takes no short sizes yet (benchmarks/short_mode.py): "
                "at full size it runs for hours and writes into benchmarks/results/")
    return ""


def _marker_before(lines: list[str], fence: int) -> tuple[str, str] | None:
    """A ``<!-- check_docs: ... -->`` on the last non-blank line before a fence."""
    k = fence - 1
    while k >= 0 and not lines[k].strip():
        k -= 1
    m = MARKER.search(lines[k]) if k >= 0 else None
    return (m.group(1), m.group(2)) if m else None


def _apply_marker(cmd: Command, marker: tuple[str, str] | None, short: bool = False) -> None:
    if marker is None:
        return
    what, arg = marker
    if what == "skip":
        cmd.skip = arg or "marked skip without a reason"
    elif what == "full-only":
        if short:
            cmd.skip = arg or "marked full-only without a reason"
        else:
            cmd.full = True
    elif what == "full":
        cmd.full = True
    elif what == "needs":
        cmd.needs = arg
    else:
        cmd.expect = int(arg)


# -- running ------------------------------------------------------------------------------------
_SHIM = '''#!{python}
"""tspend of the checked tree; under TSPEND_DOCS_SHORT=1 with short runs."""
import os, sys
sys.path.insert(0, {root!r})
sys.path.insert(1, {tools!r})
# a sweep's worker processes re-import the main module: only the main process runs main()
if __name__ == "__main__":
    argv = sys.argv[1:]
    if os.environ.get("TSPEND_DOCS_SHORT") == "1" and argv:
        from check_docs import shortened
        argv = shortened(argv)
    from tspend.cli.main import main
    sys.exit(main(argv))
'''


def shortened(argv: list[str]) -> list[str]:
    """``argv`` with short runs: ``--seeds`` at most two, the subcommand's :data:`SHORT`."""
    out = []
    for prev, a in zip([""] + argv, argv):
        if prev == "--seeds" and ":" in a:
            lo = int(a.split(":")[0] or 0)
            a = f"{lo}:{lo + 2}"
        out.append(a)
    return out + SHORT.get(out[0], [])


def _bin(folder: Path) -> None:
    folder.mkdir()
    shim = folder / "tspend"
    shim.write_text(_SHIM.format(python=sys.executable, root=str(ROOT),
                                 tools=str(ROOT / "tools")))
    shim.chmod(0o755)
    for name in ("python", "python3"):
        # a wrapper, not a link: a linked venv interpreter finds no pyvenv.cfg beside the
        # link and starts without the environment's packages
        wrapper = folder / name
        wrapper.write_text(f'#!/bin/sh\nexec {shlex.quote(sys.executable)} "$@"\n')
        wrapper.chmod(0o755)


def _repo_state() -> str:
    r = subprocess.run(["git", "status", "--porcelain", "--untracked-files=all"], cwd=ROOT,
                       capture_output=True, text=True)
    return r.stdout


def run_doc(commands: list[Command], short: bool, timeout: float, verbose: bool) -> list[Outcome]:
    """Run one document's commands in order in a scratch folder of its own."""
    outcomes = []
    with tempfile.TemporaryDirectory(prefix="tspend-docs-") as tmp:
        tmp = Path(tmp)
        work = tmp / "work"
        work.mkdir()
        for name in ("models", "examples", "scenarios", "benchmarks", "tools"):
            if (ROOT / name).exists():
                (work / name).symlink_to(ROOT / name)
        _bin(tmp / "bin")
        env = {**os.environ, "PATH": f"{tmp / 'bin'}{os.pathsep}{os.environ.get('PATH', '')}",
               "PYTHONPATH": os.pathsep.join(filter(None, [str(ROOT),
                                                           os.environ.get("PYTHONPATH")])),
               "MPLBACKEND": "Agg", "TSPEND_DOCS_SHORT": "1" if short else "0",
               # a benchmark script takes its short sizes (benchmarks/short_mode.py)
               "TSPEND_BENCH_SHORT": "1"}
        for i, cmd in enumerate(commands):
            if cmd.skip:
                continue
            if cmd.problem or cmd.kind == "inline":   # read, never run
                problem = cmd.problem or inline_problem(cmd.text)
                outcomes.append(Outcome(cmd, None, 0.0, problem, not problem))
                if verbose or problem:
                    print(f"  {'FAIL' if problem else 'ok  '} {cmd.doc}:{cmd.line} "
                          f"{'read' if cmd.kind == 'inline' else 'line'}: "
                          f"{cmd.text.splitlines()[0][:110]}" + (f"\n       {problem}"
                                                                  if problem else ""),
                          flush=True)
                continue
            if cmd.kind == "python":
                script = work / f"block_{i}.py"
                script.write_text(cmd.text)
                argv = [sys.executable, str(script)]
            else:
                argv = ["bash", "-c", cmd.text.replace("\\\n", " ")]
            t0 = time.perf_counter()
            try:
                done = subprocess.run(argv, cwd=work, capture_output=True, text=True,
                                      timeout=timeout,
                                      env={**env, "TSPEND_DOCS_SHORT": "1" if short and
                                           not cmd.full else "0"})
                status, tail = done.returncode, (done.stdout + done.stderr)[-1500:]
            except subprocess.TimeoutExpired:
                status, tail = None, f"timed out after {timeout:.0f} s"
            o = Outcome(cmd, status, time.perf_counter() - t0, tail, status == cmd.expect)
            outcomes.append(o)
            if verbose or not o.ok:
                head = cmd.text.splitlines()[0][:110]
                print(f"  {'ok  ' if o.ok else 'FAIL'} {cmd.doc}:{cmd.line} exit {status} "
                      f"(expected {cmd.expect}, {o.seconds:.1f} s): {head}", flush=True)
                if not o.ok:
                    print("       " + tail.strip().replace("\n", "\n       ")[-1200:], flush=True)
    return outcomes


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__.split("\n\n")[0] + " Full mode (no option): every command, "
        "tspend commands as written, benchmark scripts end to end at short sizes "
        "(TSPEND_BENCH_SHORT=1) in a scratch folder. tools/check_claims.py --recompute N "
        "re-derives data at full size.")
    ap.add_argument("docs", nargs="*", help="documents (default: README.md and docs/*.md)")
    ap.add_argument("--short", action="store_true",
                    help="shorten tspend runs (duration, seeds, jobs, resamples, trials) and "
                         "skip the benchmark scripts: the test suite's fast subset")
    ap.add_argument("--list", action="store_true", help="list the commands and skips; run nothing")
    ap.add_argument("--timeout", type=float, default=900.0,
                    help="seconds one command may take (1-7200)")
    ap.add_argument("-v", "--verbose", action="store_true", help="print every command's result")
    ap.add_argument("--wheel", metavar="PYTHON",
                    help="wheel mode (tools/check_docs_wheel.py): each document's first block "
                         "run by the tspend of PYTHON's environment, installed from the wheel, "
                         "in an empty folder")
    args = ap.parse_args(argv)
    if not 1 <= args.timeout <= 7200:
        ap.error(f"--timeout: {args.timeout} is outside 1..7200")
    paths = ([Path(p).resolve() for p in args.docs] if args.docs
             else [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))])
    missing = [str(p) for p in paths if not p.is_file()]
    if missing:
        print(f"check_docs: error: no such document: {missing[0]}", file=sys.stderr)
        return 2
    if args.wheel:
        from check_docs_wheel import check_wheel

        return check_wheel(args.wheel, paths, args.short, args.timeout, args.verbose)
    ran = skipped = failed = 0
    started = time.perf_counter()
    reasons: dict[str, int] = {}
    for path in paths:
        commands = extract(path, args.short)
        skips = [c for c in commands if c.skip]
        skipped += len(skips)
        for c in skips:
            reasons[c.skip] = reasons.get(c.skip, 0) + 1
            print(f"  skip {c.doc}:{c.line} ({c.skip}): {c.text.splitlines()[0][:100]}")
        if args.list:
            for c in commands:
                if not c.skip:
                    print(f"  run  {c.doc}:{c.line} [{c.kind}, exit {c.expect}]: "
                          f"{c.text.splitlines()[0][:100]}")
            ran += len(commands) - len(skips)
            continue
        before = _repo_state()
        outcomes = run_doc(commands, args.short, args.timeout, args.verbose)
        ran += len(outcomes)
        failed += sum(not o.ok for o in outcomes)
        after = _repo_state()
        if after != before:
            failed += 1
            new = sorted(set(after.splitlines()) - set(before.splitlines()))
            print(f"  FAIL {path.name}: its commands changed the repository: {new[:5]}")
    verb = "would run" if args.list else "ran"
    print(f"check_docs: {len(paths)} documents, {verb} {ran} commands"
          + ("" if args.list else f" ({ran - failed} with the expected exit status, "
             f"{failed} failed)")
          + f", skipped {skipped}: "
          + ("; ".join(f"{n} {why}" for why, n in sorted(reasons.items())) or "none")
          + ("" if args.list else f"; {'short' if args.short else 'full'} mode, wall "
             f"{time.perf_counter() - started:.0f} s"))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
