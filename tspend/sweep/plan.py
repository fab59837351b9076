"""What a sweep runs: the cartesian product of scenarios, grid values, seeds and
controller kinds, each point a :class:`Job` with the identity of its row.

Every grid point is validated exactly like ``--set`` (``tspend.scenario.override``)
before anything runs, so a bad value is one clear error and not a column of failed rows.
"""

from __future__ import annotations

import hashlib
import itertools
import json
import os
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Sequence

from tspend.config import Scenario
from tspend.runtime.errors import ScenarioError

#: where a run's recording is kept: never, only when it did not complete, always
RECORD_MODES = ("failed", "all", "none")


@dataclass(frozen=True)
class Job:
    """One closed-loop run of a sweep and the identity of its row."""

    index: int                          # position in the plan: the table's row order
    key: str                            # the row's identity (resume skips keys present)
    label: str                          # the scenario's name (the ``scenario`` column)
    scenario: Scenario                  # grid values applied, validated (shared by the seeds)
    grid: tuple[tuple[str, Any], ...]   # (key, value as its column holds it)
    seed: int                           # applied by the worker (a valid seed by construction)
    controller: str                     # the kind in the row
    run_kind: str | None                # what run() is asked for (None: the scenario's own)
    scenario_hash: str
    record: str                         # one of RECORD_MODES
    record_path: str | None             # where a recording goes if one is made
    cwd: str = ""                       # the caller's directory: relative paths mean the same


def scenario_hash(scenario: Scenario) -> str:
    """16 hex digits of SHA-256 over the scenario's text with its fixed overrides."""
    from tspend.loop.simulation import scenario_text

    return hashlib.sha256(scenario_text(scenario).encode()).hexdigest()[:16]


def own_kind(scenario: Scenario) -> str:
    """The kind the scenario's own controller reports (its ``adaptation`` picks it)."""
    return "first_type" if scenario.controller.adaptation == "first" else "second_type"


def column_value(value: Any) -> Any:
    """A grid value as its column holds it: scalars as they are, lists and tables as JSON."""
    if isinstance(value, (bool, int, float, str)):
        return value
    return json.dumps(value, sort_keys=True)


def split_values(text: str) -> list[str]:
    """``0.1,[1, 2],"a,b"`` -> ``['0.1', '[1, 2]', '"a,b"']``: commas inside brackets,
    braces or quotes do not split."""
    parts, depth, quote, start = [], 0, "", 0
    for i, ch in enumerate(text):
        if quote:
            if ch == quote:
                quote = ""
        elif ch in "\"'":
            quote = ch
        elif ch in "[{":
            depth += 1
        elif ch in "]}":
            depth -= 1
        elif ch == "," and depth == 0:
            parts.append(text[start:i])
            start = i + 1
    parts.append(text[start:])
    return [p.strip() for p in parts]


def parse_value(text: str, where: str = "--grid") -> Any:
    """One value as ``--set`` reads it: TOML (numbers, booleans, strings, lists, inline
    tables), and the bare text when it is not TOML (``adaptation=first``).

    Raises
    ------
    ScenarioError
        a line break, NUL byte or more TOML after the value, nesting beyond
        :data:`tspend.runtime.bounds.MAX_NESTING`, a number Python will not convert.
    """
    import tomllib

    from tspend.scenario import check_nesting

    if "\n" in text or "\r" in text or "\x00" in text:
        raise ScenarioError(f"{where}: a value must be one line of TOML (it contains a line "
                            f"break or a NUL byte)")
    try:
        parsed = tomllib.loads(f"v = {text}")
    except tomllib.TOMLDecodeError:
        return text
    except RecursionError:
        raise ScenarioError(f"{where}: a value is nested too deeply") from None
    except ValueError as exc:  # e.g. more digits than Python converts
        raise ScenarioError(f"{where}: {str(exc)[:120]}") from None
    if list(parsed) != ["v"]:
        raise ScenarioError(f"{where}: one value expected, got more TOML after it")
    check_nesting(parsed["v"], where)
    return parsed["v"]


def parse_grid(items: Sequence[str]) -> dict[str, list[Any]]:
    """``--grid KEY=V1,V2`` options (values in TOML, as for ``--set``) -> {key: values}."""
    grid: dict[str, list[Any]] = {}
    for item in items:
        key, sep, values = item.partition("=")
        key = key.strip()
        if not sep or not key or not values.strip():
            raise ScenarioError(f"--grid {item}: expected KEY=V1,V2,..., e.g. "
                                f"controller.eta=0.001,0.01")
        if key in grid:
            raise ScenarioError(f"--grid {key}: given twice; list all its values in one --grid")
        texts = split_values(values)
        if any(not t for t in texts):
            raise ScenarioError(f"--grid {item}: empty value in the list")
        grid[key] = [parse_value(t, f"--grid {key[:80]}") for t in texts]
    return grid


def parse_seeds(text: str) -> list[int]:
    """``A:B`` (A..B-1, as a Python range), ``N`` or ``N1,N2,...`` -> a list of seeds."""
    from tspend.runtime.bounds import MAX_RUNS, MAX_SEED

    m = re.fullmatch(r"\s*(\d{1,30})\s*:\s*(\d{1,30})\s*", text)
    try:
        if m:
            a, b = int(m.group(1)), int(m.group(2))
            if b <= a or b - 1 > MAX_SEED:
                raise ValueError
            if b - a > MAX_RUNS:
                raise ScenarioError(f"--seeds {text.strip()}: {b - a} seeds, more than a sweep "
                                    f"runs ({MAX_RUNS}); split it into smaller sweeps")
            return list(range(a, b))
        parts = text.split(",")
        if len(parts) > MAX_RUNS or not all(re.fullmatch(r"\s*\d{1,30}\s*", p) for p in parts):
            raise ValueError
        seeds = [int(s) for s in parts]
        if any(s < 0 or s > MAX_SEED for s in seeds):
            raise ValueError
        return seeds
    except ValueError:
        raise ScenarioError(f"--seeds {text[:80]}: expected A:B (seeds A to B-1, B > A), N or "
                            f"N1,N2,... with seeds from 0 to 2^63 - 1") from None


def _seed_list(seeds: int | Iterable[int] | None) -> list[int] | None:
    if seeds is None:
        return None
    if isinstance(seeds, str):
        return parse_seeds(seeds)
    from tspend.runtime.bounds import MAX_RUNS, MAX_SEED

    if isinstance(seeds, range) and len(seeds) > MAX_RUNS:
        raise ScenarioError(f"seeds: {len(seeds)} seeds, more than a sweep runs ({MAX_RUNS})")
    try:
        out = [seeds] if isinstance(seeds, int) else list(itertools.islice(seeds, MAX_RUNS + 1))
    except TypeError:
        raise ScenarioError(f"seeds: expected integers >= 0, got {seeds!r:.80}") from None
    if len(out) > MAX_RUNS:
        raise ScenarioError(f"seeds: more than a sweep runs ({MAX_RUNS})")
    if not out or any(isinstance(s, bool) or not isinstance(s, int) or not 0 <= s <= MAX_SEED
                      for s in out):
        raise ScenarioError(f"seeds: expected integers >= 0, got {seeds!r}")
    return out


def controller_list(controllers: str | Iterable[str] | None) -> list[tuple[str | None, str | None]]:
    """(what run() is asked for, the kind the row names) per controller: a plug-in spec
    ``file.py:Class`` runs as itself and is named by its kind."""
    from tspend.controllers import load

    if controllers is None:
        return [(None, None)]
    if isinstance(controllers, str):
        kinds = [c.strip() for c in controllers.split(",")]
    elif isinstance(controllers, Iterable):
        kinds = list(itertools.islice(controllers, 1001))
    else:
        raise ScenarioError(f"--controller: expected kinds (a list, or 'k1,k2'), got "
                            f"{controllers!r:.80}")
    if len(kinds) > 1000:
        raise ScenarioError("--controller: more than 1000 kinds")
    if not kinds:
        raise ScenarioError("--controller: no kind given")
    return [(spec, load(spec).name) for spec in dict.fromkeys(kinds)]


def resolve_scenarios(scenarios: Any) -> list[Scenario]:
    from tspend.scenario import load_scenario

    items = scenarios if isinstance(scenarios, (list, tuple)) else [scenarios]
    if not items:
        raise ScenarioError("sweep: no scenario given")
    out = [s if isinstance(s, Scenario) else load_scenario(s) for s in items]
    names: dict[str, str] = {}
    for s in out:
        h = scenario_hash(s)
        if names.setdefault(s.name, h) != h:
            raise ScenarioError(f"sweep: two different scenarios are both named '{s.name}'; "
                                f"rename one (the 'name' key)")
    return list({s.name: s for s in out}.values())


def row_key(label: str, grid: Iterable[tuple[str, Any]], seed: int, controller: str) -> str:
    return json.dumps([label, [[k, v] for k, v in grid], seed, controller])


def recording_path(record_dir: Path, job_label: str, seed: int, controller: str,
                   key: str) -> Path:
    """A name of its own for each row: readable parts plus a hash of the row's identity."""
    safe = re.sub(r"[^A-Za-z0-9_.-]", "_", job_label)
    digest = hashlib.sha256(key.encode()).hexdigest()[:10]
    return record_dir / f"{safe}-seed{seed}-{controller}-{digest}.rrd"


from tspend.runtime.bounds import MAX_RUNS  # noqa: E402  (constants only)


def make_plan(scenarios: Any, grid: dict[str, Sequence[Any]] | None = None,
              seeds: int | Iterable[int] | str | None = None,
              controllers: str | Iterable[str] | None = None, record: str = "none",
              record_dir: Path | None = None) -> list[Job]:
    """Every run of the sweep, in table order: scenario, grid point, seed, controller."""
    from tspend.scenario import override

    if record not in RECORD_MODES:
        raise ScenarioError(f"--record {record}: allowed: {', '.join(RECORD_MODES)}")
    from collections.abc import Mapping

    if grid is not None and not isinstance(grid, Mapping):
        raise ScenarioError(f"grid: expected a dict of dotted keys to lists of values, got "
                            f"{type(grid).__name__}")
    grid = dict(grid or {})
    if any(not isinstance(k, str) for k in grid):
        raise ScenarioError("grid: keys are dotted strings such as controller.eta")
    if "run.seed" in grid:
        raise ScenarioError("--grid run.seed: seeds are swept with --seeds (seeds= in Python)")
    for key, values in grid.items():
        if isinstance(values, (str, bytes)) or not isinstance(values, Iterable):
            raise ScenarioError(f"grid {key}: expected a list of values, got {values!r}")
        grid[key] = list(itertools.islice(values, MAX_RUNS + 1))
        if not grid[key]:
            raise ScenarioError(f"grid {key}: no values")
    seed_list = _seed_list(seeds)
    kinds = controller_list(controllers)
    keys = list(grid)
    bases = resolve_scenarios(scenarios)
    runs = len(bases) * len(kinds) * (len(seed_list) if seed_list is not None else 1)
    for values in grid.values():
        runs *= len(values)
    if runs > MAX_RUNS:
        raise ScenarioError(f"sweep: {runs} runs (scenarios x grid points x seeds x "
                            f"controllers), more than {MAX_RUNS}; split it into smaller sweeps")
    cwd = os.getcwd()
    jobs: list[Job] = []
    seen: set[str] = set()
    for base in bases:
        base_hash = scenario_hash(base)
        for point in itertools.product(*(grid[k] for k in keys)):
            changes = dict(zip(keys, point))
            try:
                at_point = override(base, **changes) if changes else base
            except ScenarioError as exc:
                raise ScenarioError(f"--grid: {exc}") from None
            columns = tuple((k, column_value(v)) for k, v in changes.items())
            for seed in seed_list if seed_list is not None else [base.run.seed]:
                for kind, name in kinds:
                    label_kind = name if name is not None else own_kind(base)
                    key = row_key(base.name, columns, seed, label_kind)
                    if key in seen:
                        continue
                    seen.add(key)
                    path = (str(recording_path(record_dir, base.name, seed, label_kind, key))
                            if record != "none" and record_dir is not None else None)
                    jobs.append(Job(len(jobs), key, base.name, at_point, columns, seed, label_kind,
                                    kind, base_hash, record if path else "none", path, cwd))
    return jobs
