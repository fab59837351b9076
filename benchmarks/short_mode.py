"""Short sizes for a benchmark script that tools/check_docs.py runs (``TSPEND_BENCH_SHORT=1``).

tools/check_docs.py runs, in its full mode, every benchmark command a document shows, end to
end, in a scratch folder, with ``TSPEND_BENCH_SHORT=1`` in the environment. A script then
takes the short sizes it names with :func:`short_defaults` or :func:`sized` (fewer seeds,
blocks, rounds, runs; shorter durations): every line of the script runs, so a broken import,
a renamed column or a changed API fails the check, but the numbers it prints are a smoke
run, not a measurement, and a timing target is not judged (:func:`judged`). Options given
on the command line still win over the short defaults. A result file the script writes by
default into the repository goes, under short mode, into the working folder instead
(:func:`out_path`): no documented command writes into the repository.

A script takes part with three lines (argparse) or one call (a constant)::

    from short_mode import short_defaults
    ap = argparse.ArgumentParser(...)
    ...
    short_defaults(ap, seeds="0:2", duration=1.0)     # before ap.parse_args()

    from short_mode import sized
    ROUNDS = sized(15, 2)

Full sizes are the script run as documented (no variable set); the fair comparison's data
are re-derived at full size by ``python tools/check_claims.py --recompute N``.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path
from typing import Any, TypeVar

ENV = "TSPEND_BENCH_SHORT"
NOTE = (f"short sizes ({ENV}=1, as tools/check_docs.py runs it): a smoke run of every "
        f"line, not a measurement; run without {ENV} for the figures")
T = TypeVar("T")


def short() -> bool:
    """Whether this run is a short one (``TSPEND_BENCH_SHORT=1``)."""
    return os.environ.get(ENV) == "1"


def _note() -> None:
    if not getattr(_note, "said", False):
        print(f"# {NOTE}", file=sys.stderr, flush=True)
        _note.said = True


def short_defaults(parser: argparse.ArgumentParser, **sizes: Any) -> None:
    """Under short mode, ``parser``'s defaults become ``sizes`` (by destination name);
    what the command line gives still wins. Call it before ``parse_args``."""
    if short():
        known = {a.dest for a in parser._actions}
        unknown = sorted(set(sizes) - known)
        if unknown:
            raise ValueError(f"short_defaults: the parser has no option {unknown[0]!r}")
        parser.set_defaults(**sizes)
        _note()


def sized(full: T, short_value: T) -> T:
    """``short_value`` under short mode, else ``full``."""
    if short():
        _note()
        return short_value
    return full


def judged() -> bool:
    """Whether a timing target decides the exit status: not in a short run (its timings
    are of a few blocks on a shared machine)."""
    return not short()


def out_path(default: str | Path) -> Path:
    """Where a result file goes by default: ``default``, or under short mode its name in the
    working folder (the checker's scratch folder), never the repository's copy."""
    p = Path(default)
    return Path(p.name) if short() else p
