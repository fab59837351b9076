"""The ``[controllers.KIND]`` tables of a scenario: per-kind settings, typed and validated.

Each baseline kind has a frozen dataclass of settings in its own module; every field is
declared with :func:`setting`, which records what the value is (a number, a vector of
length n, an n x n matrix, a choice, ...) and its documentation.  A scenario may carry

    [controllers.lqr]
    R = 0.01

and :func:`parse_kind_tables` turns those tables into the dataclasses when the scenario
is loaded, so a bad key or value stops the run before anything is written, with one line
naming the file, the key and what is allowed (``tspend.runtime.errors.ScenarioError``, exit 2).
A kind without a table runs on its documented defaults.  ``None`` in a field means
"derived from the plant when the controller is built" (each module says how).

The paper controller (``second_type``, ``first_type``) keeps its settings in
``[controller]``, as before, read the same way (:func:`read_settings` of its settings
class, :class:`tspend.config.ControllerConfig`).
"""

from __future__ import annotations

import dataclasses
import math
from typing import TYPE_CHECKING, Any, NamedTuple, Protocol

from tspend.config import POLE_CAP, ControllerConfig, setting  # noqa: F401 (re-exported)
from tspend.config.tables import Table

if TYPE_CHECKING:
    from tspend.config import Scenario

#: the paper controller's kinds: their settings live in [controller]
PAPER_KINDS = ("second_type", "first_type")


class KindSettings:
    """Base of every kind's settings dataclass: :meth:`check` validates across fields;
    ``SEARCH`` declares what ``tspend tune`` searches (none by default)."""

    SEARCH: dict = {}

    def check(self, n: int) -> tuple[str, str] | None:
        """``(key, problem)`` when the settings do not fit a plant of order ``n``."""
        return None


def _value(r: Table, f: dataclasses.Field, n: int) -> Any:
    meta, key = f.metadata, key_of(f)
    kind = meta["kind"]
    high = meta.get("high")
    if kind == "number":
        v = r.number(key, low=meta["low"], strict=meta["strict"])
        if high is not None and v > high:
            raise r.error(key, f"must be at most {high:g}, got {v:g}")
        return v
    if kind == "integer":
        return r.integer(key, low=int(meta["low"] or 0), high=None if high is None else int(high))
    if kind == "bool":
        v = r.table[key]
        if not isinstance(v, bool):
            raise r.error(key, f"must be true or false, got {v!r}")
        return v
    if kind == "choice":
        return r.string(key, choices=meta["choices"])
    if kind == "vector":
        length = n if meta["length"] == "n" else n - 1
        values = r.numbers(key, length)
        if meta["low"] is not None and any(v <= meta["low"] if meta["strict"] else v < meta["low"]
                                           for v in values):
            op = ">" if meta["strict"] else ">="
            raise r.error(key, f"every entry must be {op} {meta['low']:g}, got {list(values)}")
        return values
    if kind == "matrix":
        return r.matrix(key, n)
    if kind == "list":
        # a length the plant decides (the full state's): checked when the kind is built
        values = r.numbers(key)
        if meta["low"] is not None and any(v < meta["low"] for v in values):
            raise r.error(key, f"every entry must be >= {meta['low']:g}, got {list(values)}")
        return values
    if kind == "sets":
        return r.set_specs(key, n, min_terms=meta.get("min_terms", 2))
    if kind == "set":
        return r.set_spec(key)
    if kind == "interval":
        return r.interval(key, f.default)
    if kind == "string":
        return r.string(key)
    raise AssertionError(f"unknown setting kind {kind!r}")


def key_of(f: dataclasses.Field) -> str:
    """The key of a settings field in the scenario file."""
    return f.metadata.get("name") or f.name


def read_settings(r: Table, cls: type, n: int, context: str = "") -> Any:
    """The settings of class ``cls`` in table ``r`` for a plant of order ``n``: every field
    declared with :func:`setting` read by its metadata (keys in a sub-table ``table`` read
    there), the rest at their defaults (``per_order``: the default for order ``n``), then
    ``check(n)``; unknown keys and bad values are one-line errors naming file, key and what
    is allowed."""
    fields = dataclasses.fields(cls)
    tables = {f.metadata.get("table") for f in fields} - {None}
    r.check_keys(tuple(key_of(f) for f in fields if not f.metadata.get("table"))
                 + tuple(sorted(tables)), context)
    values = {}
    for name in (None, *sorted(tables)):
        t = r if name is None else r.table_of(name)
        own = [f for f in fields if f.metadata.get("table") == name]
        if name is not None:
            t.check_keys(tuple(key_of(f) for f in own))
        for f in own:
            if t.has(key_of(f)):
                values[f.name] = _value(t, f, n)
            elif f.metadata.get("per_order") is not None:
                values[f.name] = f.metadata["per_order"](n)
    settings = cls(**values)
    problem = settings.check(n)
    if problem:
        key, message = problem
        raise r.error(key, message)
    return settings


def parse_kind_tables(r: Table, n: int, kinds: dict[str, type[KindSettings]]
                      ) -> tuple[tuple[str, KindSettings], ...]:
    """The ``[controllers]`` table: ``(kind, settings)`` pairs, validated for order ``n``;
    ``kinds`` maps each kind to its settings class (``tspend.controllers.SETTINGS``)."""
    out = []
    for kind in r.table:
        if kind in PAPER_KINDS:
            raise r.error(kind, "the paper controller's settings live in [controller]; "
                                f"[controllers.KIND] tables are for: {', '.join(kinds)}")
        if kind not in kinds:
            raise r.error(kind, f"unknown controller kind; allowed: {', '.join(kinds)}")
        out.append((kind, read_settings(r.table_of(kind), kinds[kind], n, f"for kind '{kind}'")))
    return tuple(out)


def settings_for(scenario: "Scenario", cls: type[KindSettings]) -> Any:
    """The scenario's settings of class ``cls``: its ``[controllers.KIND]`` table, else
    the defaults."""
    for _, s in scenario.controllers:
        if isinstance(s, cls):
            return s
    return cls()


def finite_or(value: float | None, fallback: float) -> float:
    """``value`` when given, else the plant-derived ``fallback`` (must be finite)."""
    out = fallback if value is None else value
    if not math.isfinite(out):
        raise ValueError(f"derived setting is not finite: {out}")
    return float(out)


# -- what tspend tune searches ---------------------------------------------------------------
class Search(NamedTuple):
    """One tuned setting: a number drawn from ``[low, high]`` (on a log scale when ``log``)
    and how it becomes the setting's value (``form``):

    * ``"number"``: the value itself;
    * ``"diagonal"``: ``value * I`` (n x n), a scale of an identity weight (Q);
    * ``"poles"``: ``lambda_1 .. lambda_n`` with ``s^n + lambda_n s^(n-1) + .. + lambda_1 =
      (s + value)^n``: every root at ``-value``, so the vector is Hurwitz by construction.

    Each kind declares a table ``SEARCH = {key: (low, high, "log"|"linear"[, form])}`` on
    its settings class (the paper's kinds: :data:`PAPER_SEARCH`), keyed by the name in
    the scenario file.
    """

    low: float
    high: float
    log: bool = False
    form: str = "number"

    def value(self, x: float, n: int) -> Any:
        """The setting's value in the scenario file for the drawn number ``x`` (order n)."""
        if self.form == "number":
            return float(x)
        if self.form == "diagonal":
            return [[float(x) if i == j else 0.0 for j in range(n)] for i in range(n)]
        if self.form == "poles":
            return [float(math.comb(n, i) * x ** (n - i)) for i in range(n)]
        raise AssertionError(f"unknown search form {self.form!r}")


#: what ``tspend tune`` searches for the paper's kinds ([controller]): their settings
#: class's declaration, as every kind's (its lambda poles capped by POLE_CAP, as every kind's)
PAPER_SEARCH = ControllerConfig.SEARCH


def search_table(kind: str, table: dict) -> dict[str, Search]:
    """A kind's search declaration (``{key: (low, high, "log"|"linear", form?)}``) as
    :class:`Search` entries, each checked."""
    out = {}
    for key, spec in table.items():
        low, high, scale, *form = spec
        if scale not in ("log", "linear") or not low < high or (scale == "log" and low <= 0):
            raise AssertionError(f"bad search declaration of {kind}.{key}: {spec!r}")
        out[key] = Search(float(low), float(high), scale == "log", *form)
    return out
