"""The one reader of scenario tables: every table of a scenario file goes through :class:`Table`.

A :class:`Table` reads the keys of one TOML table by type (a number, an integer, a string
from a set of choices, a list of numbers, an n x n matrix, fuzzy-set tables), each problem a
:class:`~tspend.runtime.errors.ScenarioError` whose one-line message names the file, the dotted key
and what is allowed, e.g. ``scenarios/x.toml: controller.eta: must be > 0, got -1``.

:func:`read_fields` maps a table onto a frozen dataclass: its fields are the allowed keys,
each read by its type and checked by its ``metadata`` (``low``, ``strict``, ``choices``).
The scenario's sections (:mod:`tspend.scenario`), the plant configurations of every domain
(:mod:`tspend.plants`), the ``[task]`` table and the controllers' ``[controllers.KIND]``
settings (:mod:`tspend.controllers.settings`) all read through here.
"""

from __future__ import annotations

import dataclasses
import difflib
import math
from typing import Any

import numpy as np

from tspend.config import SetSpec
from tspend.runtime.errors import ScenarioError
from tspend.runtime.bounds import MAX_LIST, MAX_TERMS

__all__ = ["Table", "read_fields", "SET_KEYS"]

#: the keys of a fuzzy-set table {terms, lo, hi}
SET_KEYS = ("terms", "lo", "hi")


def shown_key(key: str) -> str:
    """A key as an error line shows it: quoted as Python would when TOML's quoted keys
    let it hold a line break, a control character or outer spaces (one line stays one)."""
    return key if key and key.isprintable() and key.strip() == key else repr(key)


class Table:
    """Reads keys of one table, each error naming the file and the dotted key."""

    def __init__(self, path: str, table: dict, prefix: str = "") -> None:
        self.path, self.table, self.prefix = path, table, prefix

    def error(self, key: str, problem: str) -> ScenarioError:
        return ScenarioError(f"{self.path}: {self.prefix}{shown_key(key)}: {problem}")

    def check_keys(self, allowed: tuple[str, ...], context: str = "") -> None:
        for key in self.table:
            if key not in allowed:
                close = difflib.get_close_matches(key, allowed, n=1)
                did = f" (did you mean '{close[0]}'?)" if close else ""
                where = f" {context}" if context else ""
                raise self.error(key, f"unknown key{did}; allowed{where}: {', '.join(allowed)}")

    def has(self, key: str) -> bool:
        return key in self.table

    def number(self, key: str, default: float | None = None, *, low: float | None = None,
               strict: bool = False) -> float:
        if key not in self.table:
            if default is None:
                raise self.error(key, "missing (a number is required)")
            return default
        v = self.table[key]
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise self.error(key, f"must be a number, got {type(v).__name__} {v!r}")
        v = float(v)
        if not math.isfinite(v):
            raise self.error(key, f"must be finite, got {v}")
        if low is not None and (v <= low if strict else v < low):
            raise self.error(key, f"must be {'>' if strict else '>='} {low:g}, got {v:g}")
        return v

    def integer(self, key: str, default: int | None = None, *, low: int = 0,
                high: int | None = None) -> int:
        if key not in self.table:
            if default is None:
                raise self.error(key, "missing (an integer is required)")
            return default
        v = self.table[key]
        if isinstance(v, bool) or not isinstance(v, int):
            raise self.error(key, f"must be an integer, got {type(v).__name__} {v!r}")
        if v < low or (high is not None and v > high):
            allowed = f">= {low}" if high is None else f"from {low} to {high}"
            shown = str(v) if abs(v) < 10**15 else f"an integer of {len(str(abs(v)))} digits"
            raise self.error(key, f"must be {allowed}, got {shown}")
        return v

    def boolean(self, key: str, default: bool | None = None) -> bool:
        if key not in self.table:
            if default is None:
                raise self.error(key, "missing (true or false is required)")
            return default
        v = self.table[key]
        if not isinstance(v, bool):
            raise self.error(key, f"must be true or false, got {v!r}")
        return v

    def string(self, key: str, default: str | None = None,
               choices: tuple[str, ...] | None = None) -> str:
        if key not in self.table:
            if default is None:
                raise self.error(key, "missing (a string is required)")
            return default
        v = self.table[key]
        if not isinstance(v, str):
            raise self.error(key, f"must be a string, got {type(v).__name__} {v!r}")
        if choices is not None and v not in choices:
            close = difflib.get_close_matches(v, choices, n=1)
            did = f" (did you mean '{close[0]}'?)" if close else ""
            raise self.error(key, f"{v!r} is not allowed{did}; allowed: {', '.join(choices)}")
        return v

    def numbers(self, key: str, length: int | None = None,
                default: tuple[float, ...] | None = None) -> tuple[float, ...]:
        if key not in self.table:
            if default is None:
                raise self.error(key, "missing (a list of numbers is required)")
            return default
        v = self.table[key]
        if not isinstance(v, list) or any(isinstance(a, bool) or not isinstance(a, (int, float))
                                          for a in v):
            raise self.error(key, f"must be a list of numbers, got {v!r}")
        if length is not None and len(v) != length:
            raise self.error(key, f"must have {length} entries, got {len(v)}")
        if len(v) > MAX_LIST:
            raise self.error(key, f"at most {MAX_LIST} entries, got {len(v)}")
        out = tuple(float(a) for a in v)
        if not all(math.isfinite(a) for a in out):
            raise self.error(key, f"must be finite, got {v!r}")
        return out

    def strings(self, key: str, default: tuple[str, ...] | None = None,
                choices: tuple[str, ...] | None = None) -> tuple[str, ...]:
        if key not in self.table:
            if default is None:
                raise self.error(key, "missing (a list of strings is required)")
            return default
        v = self.table[key]
        if not isinstance(v, list) or not all(isinstance(a, str) for a in v):
            raise self.error(key, f"must be a list of strings, got {v!r}")
        if len(v) > MAX_LIST:
            raise self.error(key, f"at most {MAX_LIST} entries, got {len(v)}")
        for a in v:
            if choices is not None and a not in choices:
                close = difflib.get_close_matches(a, choices, n=1)
                did = f" (did you mean '{close[0]}'?)" if close else ""
                raise self.error(key, f"{a!r} is not allowed{did}; allowed: {', '.join(choices)}")
        return tuple(v)

    def interval(self, key: str, default: tuple[float, float]) -> tuple[float, float]:
        lo, hi = self.numbers(key, 2, default)
        if lo > hi:
            raise self.error(key, f"interval [lo, hi] needs lo <= hi, got [{lo:g}, {hi:g}]")
        return lo, hi

    def matrix(self, key: str, n: int, default: Any = None) -> tuple[tuple[float, ...], ...]:
        """An n x n symmetric positive definite matrix as a list of rows."""
        if key not in self.table:
            if default is None:
                raise self.error(key, f"missing (an {n}x{n} matrix is required)")
            return default
        v = self.table[key]
        ok = (isinstance(v, list) and len(v) == n
              and all(isinstance(row, list) and len(row) == n for row in v))
        if not ok:
            raise self.error(key, f"must be an {n}x{n} list of lists, got {v!r}")
        rows = tuple(Table(self.path, {key: row}, self.prefix).numbers(key, n) for row in v)
        M = np.array(rows)
        if not np.allclose(M, M.T):
            raise self.error(key, "must be symmetric")
        if np.linalg.eigvalsh(M).min() <= 0.0:
            raise self.error(key, f"must be positive definite (eigenvalues "
                                  f"{np.linalg.eigvalsh(M)})")
        return rows

    def set_spec(self, key: str, min_terms: int = 1) -> SetSpec:
        """A fuzzy-set table ``{terms, lo, hi}`` under ``key``."""
        t = self.table[key]
        if not isinstance(t, dict):
            raise self.error(key, f"must be a table {{terms = .., lo = .., hi = ..}}, got {t!r}")
        return Table(self.path, t, f"{self.prefix}{shown_key(key)}.").as_set_spec(min_terms)

    def as_set_spec(self, min_terms: int = 1) -> SetSpec:
        """This table as ``{terms, lo, hi}``."""
        self.check_keys(SET_KEYS)
        terms = self.integer("terms", None, low=min_terms, high=MAX_TERMS)
        lo, hi = self.number("lo"), self.number("hi")
        if lo >= hi:
            raise self.error("lo", f"interval needs lo < hi, got lo = {lo:g}, hi = {hi:g}")
        return SetSpec(terms, lo, hi)

    def set_specs(self, key: str, n: int, min_terms: int = 1) -> tuple[SetSpec, ...]:
        """A list of ``n`` fuzzy-set tables (one per state)."""
        v = self.table[key]
        if not isinstance(v, list) or len(v) != n or not all(isinstance(t, dict) for t in v):
            raise self.error(key, f"must be a list of {n} tables {{terms, lo, hi}} (one per "
                                  f"state), got {v!r}")
        return tuple(Table(self.path, t, f"{self.prefix}{shown_key(key)}[{i}].").as_set_spec(min_terms)
                     for i, t in enumerate(v))

    def table_of(self, key: str, required: bool = False) -> "Table":
        v = self.table.get(key, None)
        if v is None:
            if required:
                raise self.error(key, "missing table")
            v = {}
        if not isinstance(v, dict):
            raise self.error(key, f"must be a table, got {type(v).__name__}")
        return Table(self.path, v, f"{self.prefix}{shown_key(key)}.")


def read_fields(r: Table, cls: type, context: str, skip: tuple[str, ...] = ()) -> dict[str, Any]:
    """Every field of dataclass ``cls`` present in the table, read by its type and checked
    by its metadata (``low``, ``strict``, ``choices``); unknown keys are errors.  A field
    whose metadata says ``internal`` is set by tspend, not read from a table."""
    fields = {f.name: f for f in dataclasses.fields(cls) if not f.metadata.get("internal")}
    r.check_keys(tuple(fields), context)
    values: dict[str, Any] = {}
    for name, f in fields.items():
        if name in skip or not r.has(name):
            continue
        meta, default = f.metadata, f.default
        if isinstance(default, bool):
            values[name] = r.boolean(name)
        elif isinstance(default, int) and f.type in ("int", int):
            values[name] = r.integer(name, None, low=int(meta.get("low", 0)))
        elif isinstance(default, float):
            values[name] = r.number(name, None, low=meta.get("low"),
                                    strict=meta.get("strict", False))
        elif isinstance(default, str):
            values[name] = r.string(name, None, meta.get("choices"))
        elif isinstance(default, tuple) and meta.get("strings"):
            values[name] = r.strings(name, None, meta.get("choices"))
        elif isinstance(default, tuple):
            values[name] = r.numbers(name)
            if any(v < 0 for v in values[name]) and "low" in meta:
                raise r.error(name, f"entries must be >= {meta['low']:g}")
    return values
