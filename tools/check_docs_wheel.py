"""The wheel mode of tools/check_docs.py: the first block of README.md and of each
docs/*.md that has a command to run, run as written by tspend installed from its wheel,
in an empty folder that holds nothing of this checkout.

    pip wheel --no-deps -w dist .
    python3 -m venv /tmp/w && /tmp/w/bin/pip install dist/tspend-*.whl
    python tools/check_docs.py --wheel /tmp/w/bin/python                 # every document
    python tools/check_docs.py --wheel /tmp/w/bin/python --short README.md

What differs from the checkout's check: ``tspend``, ``python`` and ``python3`` are the
environment's (no PYTHONPATH to this checkout); the scratch folder is empty (no models/,
examples/ or scenarios/ linked in: the files the wheel ships must serve); and only each
document's first block with a command to run is run (in README.md the tour: its first two
blocks install). Commands that need the checkout itself (``benchmarks/``, ``tools/``) and
the usual skips (a viewer, an install) are skipped, each named. ``--short`` shortens the
runs as the checkout's check does; without it every command runs as the document writes it.

Exit 0 when every command gave its expected status and the checkout is as it was, 1
otherwise, 2 when the environment imports tspend from this checkout (not a wheel's test).
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import tempfile
import time
from pathlib import Path

from check_docs import ROOT, Command, extract

#: commands that need this checkout, not the wheel: skipped with this reason
CHECKOUT_ONLY = (r"^(nice\s+)?python3?\s+(benchmarks|tools)/",
                 "a script of the checkout (benchmarks/, tools/): not in the wheel")
#: tspend of the wheel's environment; under TSPEND_DOCS_SHORT=1 with short runs
_SHIM = '''#!{python}
import os, sys
sys.path.insert(0, {tools!r})  # check_docs.shortened only: stdlib, no tspend
if __name__ == "__main__":  # a sweep's workers re-import this script
    argv = sys.argv[1:]
    if os.environ.get("TSPEND_DOCS_SHORT") == "1" and argv:
        from check_docs import shortened
        argv = shortened(argv)
    from tspend.cli.main import main
    sys.exit(main(argv))
'''


def first_block(path: Path, short: bool) -> list[Command]:
    """The commands of the document's first fenced block that has one to run (a block of
    installs only, or of skipped lines, is passed over: the README's quick start)."""
    lines = path.read_text(encoding="utf-8").splitlines()
    fences = [i + 1 for i, line in enumerate(lines) if re.match(r"^\s*```", line)]
    commands = extract(path, short)
    for start, end in zip(fences[::2], fences[1::2]):
        inside = [c for c in commands if start < c.line < end]
        for c in inside:
            if not c.skip and re.search(CHECKOUT_ONLY[0], c.text):
                c.skip = CHECKOUT_ONLY[1]
        if any(not c.skip for c in inside):
            return inside
    return []


def _bin(folder: Path, python: str) -> None:
    folder.mkdir()
    (folder / "tspend").write_text(_SHIM.format(python=python, tools=str(ROOT / "tools")))
    (folder / "tspend").chmod(0o755)
    for name in ("python", "python3"):
        (folder / name).write_text(f'#!/bin/sh\nexec {shlex.quote(python)} "$@"\n')
        (folder / name).chmod(0o755)


def from_the_wheel(python: str) -> str:
    """"" when ``python`` imports tspend from outside this checkout, else why not."""
    with tempfile.TemporaryDirectory() as empty:
        env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
        done = subprocess.run([python, "-c", "import tspend; print(tspend.__file__)"],
                              cwd=empty, env=env, capture_output=True, text=True)
    where = done.stdout.strip()
    if done.returncode:
        return f"{python} cannot import tspend: {done.stderr.strip()[-300:]}"
    if Path(where).resolve().is_relative_to(ROOT):
        return f"{python} imports tspend from this checkout ({where}), not from a wheel"
    return ""


def run_first_blocks(python: str, paths: list[Path], short: bool, timeout: float,
                     verbose: bool) -> tuple[int, int, int]:
    """(ran, failed, skipped) over the documents' first blocks, each document in an empty
    folder of its own; a document whose commands change the checkout counts as failed."""
    ran = failed = skipped = 0
    state = ["git", "status", "--porcelain", "--untracked-files=all"]
    for path in paths:
        commands = first_block(path, short)
        before = subprocess.run(state, cwd=ROOT, capture_output=True, text=True).stdout
        with tempfile.TemporaryDirectory(prefix="tspend-wheel-docs-") as tmp:
            work, tools = Path(tmp) / "work", Path(tmp) / "bin"
            work.mkdir()
            _bin(tools, python)
            env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
            env.update(PATH=f"{tools}{os.pathsep}{env.get('PATH', '')}", MPLBACKEND="Agg")
            for cmd in commands:
                if cmd.skip:
                    skipped += 1
                    print(f"  skip {cmd.doc}:{cmd.line} ({cmd.skip}): "
                          f"{cmd.text.splitlines()[0][:90]}")
                    continue
                ran += 1
                failed += not _run_one(cmd, work, env, short, timeout, verbose)
        after = subprocess.run(state, cwd=ROOT, capture_output=True, text=True).stdout
        if after != before:
            failed += 1
            changed = sorted(set(after.splitlines()) ^ set(before.splitlines()))
            print(f"  FAIL {path.name}: the checkout changed while its commands ran: {changed[:5]}")
    return ran, failed, skipped


def _run_one(cmd: Command, work: Path, env: dict, short: bool, timeout: float,
             verbose: bool) -> bool:
    """Run one command in ``work``; True when it exits as the document says."""
    if cmd.kind == "python":
        script = work / f"block_{cmd.line}.py"
        script.write_text(cmd.text)
        argv = ["python", str(script)]
    else:
        argv = ["bash", "-c", cmd.text.replace("\\\n", " ")]
    started = time.perf_counter()
    try:
        done = subprocess.run(argv, cwd=work, capture_output=True, text=True, timeout=timeout,
                              env={**env, "TSPEND_DOCS_SHORT": "1" if short and not cmd.full
                                   else "0"})
        status, tail = done.returncode, (done.stdout + done.stderr)[-1200:]
    except subprocess.TimeoutExpired:
        status, tail = None, f"timed out after {timeout:.0f} s"
    ok = status == cmd.expect
    if verbose or not ok:
        print(f"  {'ok  ' if ok else 'FAIL'} {cmd.doc}:{cmd.line} exit {status} (expected "
              f"{cmd.expect}, {time.perf_counter() - started:.1f} s): "
              f"{cmd.text.splitlines()[0][:100]}", flush=True)
        if not ok:
            print("       " + tail.strip().replace("\n", "\n       "), flush=True)
    return ok


def check_wheel(python: str, paths: list[Path], short: bool, timeout: float,
                verbose: bool) -> int:
    """tools/check_docs.py --wheel PYTHON: the exit status (module docstring)."""
    problem = from_the_wheel(python)
    if problem:
        print(f"check_docs: error: --wheel: {problem}")
        return 2
    started = time.perf_counter()
    ran, failed, skipped = run_first_blocks(python, paths, short, timeout, verbose)
    print(f"check_docs: wheel mode ({python}), {len(paths)} documents' first blocks: ran "
          f"{ran} commands ({ran - failed} with the expected exit status, {failed} failed), "
          f"skipped {skipped}; {'short' if short else 'full'} runs, wall "
          f"{time.perf_counter() - started:.0f} s")
    return 1 if failed else 0


__all__ = ["CHECKOUT_ONLY", "check_wheel", "first_block", "from_the_wheel"]
