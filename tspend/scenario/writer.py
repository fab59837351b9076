"""A scenario as TOML: the writer of TOML text, and a scenario resolved to every key.

:func:`resolved_document` is what ``tspend show`` prints: the scenario's own tables with
its overrides applied, every key it left out filled in with the value the loader gave it
(the defaults, the [task] and [safety] tables, every controller kind's settings), and
every file it names (the MJCF, a policy, a plan, a CSV reference) written so that it is
found from any folder: relative to the shipped data when it is shipped, else absolute.
:func:`resolved_toml` checks that the text reads back as the same scenario.
"""

from __future__ import annotations

import dataclasses
import json
import math
import re
from pathlib import Path
from typing import Any

__all__ = ["dump_toml", "resolved_document", "resolved_toml"]

_BARE = re.compile(r"^[A-Za-z0-9_-]+$")


def _key(k: str) -> str:
    return k if _BARE.match(k) else json.dumps(k)


def _value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)  # the shortest text that reads back as the same double
    if isinstance(v, str):
        return json.dumps(v)  # a TOML basic string is a JSON string for these characters
    if isinstance(v, list):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{_key(k)} = {_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(f"cannot write {type(v).__name__} as TOML")


def dump_toml(doc: dict, _path: tuple[str, ...] = ()) -> str:
    """``doc`` (what ``tomllib`` reads) as TOML: scalars and arrays first, then each
    sub-table under its ``[dotted.header]``; arrays of tables are written inline."""
    lines = [f"{_key(k)} = {_value(v)}" for k, v in doc.items() if not isinstance(v, dict)]
    out = "\n".join(lines) + ("\n" if lines else "")
    for k, v in doc.items():
        if isinstance(v, dict):
            path = _path + (k,)
            body = dump_toml(v, path)
            header = "[" + ".".join(_key(p) for p in path) + "]\n"
            out += ("\n" if out else "") + header + body
    return out



def _plain(value: Any) -> Any:
    """A loaded value as the scenario file writes it (tuples as arrays, SetSpec as tables),
    or None where TOML has nothing to say it with (the key is then left out: its default)."""
    from tspend.config import SetSpec

    if value is None:
        return None
    if isinstance(value, SetSpec):
        return {"terms": value.terms, "lo": value.lo, "hi": value.hi}
    if isinstance(value, (tuple, list)):
        items = [_plain(v) for v in value]
        return None if any(v is None for v in items) else items
    if isinstance(value, (bool, int, float, str)):
        return value
    return None  # a nested configuration: written only where the file wrote it


def _fill(table: dict, obj: Any, keys: dict[str, str] | None = None,
          skip: tuple[str, ...] = (), unset: bool = False) -> dict:
    """``table`` with each field of the dataclass ``obj`` it lacks, under its file key
    (``keys`` maps a field to its key where they differ). Fields tspend sets itself
    (metadata ``internal``) are not keys of the file; ``unset``: also leave out "", empty
    arrays and infinite values, which stand for "not set"."""
    keys = keys or {}
    for f in dataclasses.fields(obj):
        key = keys.get(f.name, f.name)
        if f.name in skip or key in table or f.metadata.get("internal"):
            continue
        value = _plain(getattr(obj, f.name))
        if unset and (value in ("", []) or (isinstance(value, float)
                                             and not math.isfinite(value))):
            continue
        if value is not None:
            table[key] = value
    return table


def _portable_file(path: str, scenario_path: str) -> str:
    """``path`` as found from any folder: relative to the shipped data, else absolute."""
    from pathlib import Path

    from tspend.shipped import data_root, locate

    found = locate(path, scenario_path)
    if found is None:
        return path  # the loader names the missing file when it is used
    try:
        return found.resolve().relative_to(data_root().resolve()).as_posix()
    except ValueError:
        return str(Path(found).resolve())


def resolved_document(scenario) -> dict:
    """The scenario (a :class:`~tspend.config.Scenario`) as a TOML document with every key."""
    from tspend.controllers import settings_classes
    from tspend.controllers.settings import key_of, settings_for
    from tspend.scenario import DISTURBANCE_KINDS, REFERENCE_KINDS, parse_toml, set_dotted

    raw = parse_toml(scenario.text, scenario.path or "<string>")
    for key, value in scenario.overrides:
        set_dotted(raw, key, value, scenario.path)
    raw["name"] = scenario.name
    raw["description"] = scenario.description
    run = _fill(raw.setdefault("run", {}), scenario.run)
    if run.get("controller") == "":
        del run["controller"]  # "" is the paper's [controller]: the key left out
    plant = _fill(raw.setdefault("plant", {}), scenario.plant)
    for signal, kinds, table in ((scenario.reference, REFERENCE_KINDS, "reference"),
                                 (scenario.disturbance, DISTURBANCE_KINDS, "disturbance")):
        doc = raw.setdefault(table, {})
        doc.setdefault("kind", next(k for k, cls in kinds.items() if type(signal) is cls))
        _fill(doc, signal)
    c = scenario.controller
    ctrl = _fill(raw.setdefault("controller", {}), c, keys={"lam": "lambda"},
                 skip=("state_sets", "u_sets", "e_delta_sets", "x_norm_sets"))
    sets = ctrl.setdefault("sets", {})
    sets.setdefault("states", _plain(c.state_sets))
    for key, value in (("u", c.u_sets), ("e_delta", c.e_delta_sets), ("x_norm", c.x_norm_sets)):
        sets.setdefault(key, _plain(value))
    kinds = raw.setdefault("controllers", {})
    for kind, cls in settings_classes().items():
        settings = settings_for(scenario, cls)
        table = _fill(dict(kinds.get(kind, {})), settings, unset=True,
                      keys={f.name: key_of(f) for f in dataclasses.fields(settings)})
        if table:  # an empty table would be read as set: left out, its defaults hold
            kinds[kind] = table
    _fill(raw.setdefault("effects", {}), scenario.effects, unset=True)
    task = _fill(raw.setdefault("task", {}), scenario.task, skip=("state_bounds",))
    task.setdefault("constraints", {}).setdefault("defaults", scenario.task.constraints.defaults)
    _fill(raw.setdefault("safety", {}), scenario.safety)
    # files: found from wherever the printed scenario is saved
    if isinstance(plant.get("model"), str) and plant["model"]:
        plant["model"] = _portable_file(plant["model"], scenario.path)
    for table, key in (("policy", "path"), ("tvlqr", "plan")):
        value = kinds.get(table, {}).get(key)
        if isinstance(value, str) and value:
            kinds[table][key] = _portable_file(value, scenario.path)
    ref = raw["reference"]
    if ref.get("kind") == "csv" and isinstance(ref.get("path"), str):
        ref["path"] = _portable_file(ref["path"], scenario.path)
    return raw


def _comparable(scenario):
    """The scenario without where it came from: what a run depends on (each controller
    kind's settings, whether its table was written or its defaults hold)."""
    from tspend.controllers import settings_classes
    from tspend.controllers.settings import settings_for

    from tspend.shipped import locate

    def found(config, names=("path", "plan")):
        """``config`` with each file setting the file it finds, however it is written (a
        path relative to the scenario's folder reads back as the shipped or absolute path
        :func:`_portable_file` writes)."""
        if not dataclasses.is_dataclass(config):
            return config
        files = {f.name: str(Path(hit).resolve()) for f in dataclasses.fields(config)
                 if f.name in names and isinstance(getattr(config, f.name), str)
                 and (hit := locate(getattr(config, f.name), scenario.path)) is not None}
        return dataclasses.replace(config, **files)

    kinds = tuple((kind, found(settings_for(scenario, cls)))
                  for kind, cls in settings_classes().items())
    return dataclasses.replace(scenario, name="", description="", path="", text="",
                               overrides=(), controllers=kinds,
                               plant=found(scenario.plant, ("model",)),
                               reference=found(scenario.reference, ("path",)))


def resolved_toml(scenario) -> str:
    """:func:`resolved_document` as TOML text, checked to read back as the same scenario
    (AssertionError if not: a bug, never a silently different scenario)."""
    from tspend.scenario import parse_scenario

    text = dump_toml(resolved_document(scenario))
    again = parse_scenario(text, scenario.path or "<string>")
    if _comparable(again) != _comparable(scenario):
        raise AssertionError(f"{scenario.name}: the resolved scenario does not read back as "
                             f"the same scenario")
    return text
