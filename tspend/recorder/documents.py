"""The run's markdown documents: run, scenario, status and metrics."""

from __future__ import annotations

import dataclasses
import json
import os
import tomllib
from pathlib import Path
from typing import Sequence

import numpy as np

from tspend.loop.sinks import RunEnd, RunInfo
from tspend.shipped import data_root


def _json_default(obj: object) -> object:
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    return str(obj)


def _fmt(value: object) -> str:
    if isinstance(value, (float, np.floating)):
        return f"{float(value):.6g}"
    if isinstance(value, (dict, list, tuple, np.ndarray)):
        return "`" + json.dumps(value, default=_json_default) + "`"
    return str(value)


def _md_table(rows: Sequence[tuple[str, object]], header: tuple[str, str] = ("key", "value")) -> str:
    lines = [f"| {header[0]} | {header[1]} |", "| --- | --- |"]
    # a cell is one line: escape the column separator, fold newlines (tracebacks, messages)
    lines += ["| " + str(k) + " | " + _fmt(v).replace("|", r"\|").replace("\n", "<br>") + " |"
              for k, v in rows]
    return "\n".join(lines)


def portable_path(path: object) -> str:
    """``path`` as a recording may show it: relative to the working directory or to the
    shipped data (``models/cartpole.xml``) when inside one, else the file's name alone.  Nothing in a
    recording refers to the machine it was made on."""
    text = str(path)
    if not text or not os.path.isabs(text):
        return text
    resolved = Path(text).resolve()
    for base in (Path.cwd().resolve(), data_root()):
        try:
            return resolved.relative_to(base).as_posix()
        except ValueError:
            continue
    return resolved.name


def _declared_kind(info: RunInfo) -> str | None:
    try:
        return str(tomllib.loads(info.scenario_text).get("plant", {}).get("kind", "")) or None
    except tomllib.TOMLDecodeError:
        return None


def run_markdown(info: RunInfo) -> str:
    """Markdown summary of the run's identity."""
    rows: list[tuple[str, object]] = [
        ("scenario", info.scenario_name), ("scenario file", portable_path(info.scenario_path)),
        ("seed", info.seed), ("tspend version", info.version), ("plant kind", info.plant_kind),
        ("controller kind", info.controller_kind),
        ("order n", info.order), ("dt (s)", info.dt), ("duration (s)", info.duration),
        ("steps", info.steps),
        ("model inputs", ", ".join(i.name for i in info.model_inputs)),
        ("compensator inputs", ", ".join(i.name for i in info.compensator_inputs)),
        ("plant extras", ", ".join(info.extras)),
    ]
    if info.drawing is not None:
        rows += [(f"plant: {k}", portable_path(v) if k == "mjcf" else v)
                 for k, v in info.drawing.document().items()]
    return f"# Run: {info.scenario_name}\n\n" + _md_table(rows)


def scenario_markdown(info: RunInfo) -> str:
    """The scenario's TOML; when the run used another plant kind than the file declares
    (the cross-check runs one scenario on both backends), says so first and appends the
    override to the TOML, so the document describes the run it belongs to."""
    text = info.scenario_text
    note = ""
    declared = _declared_kind(info)
    if declared is not None and declared != info.plant_kind:
        note = (f"**This run used `plant.kind = \"{info.plant_kind}\"`**; the file declares "
                f"`\"{declared}\"` (the cross-check runs the scenario on both backends).\n\n")
        text = (f"{text.rstrip()}\n\n# overridden for this run:\n"
                f"#   plant.kind = \"{info.plant_kind}\"\n")
    return (f"# Scenario `{info.scenario_name}` on `{info.plant_kind}`\n\n{note}"
            f"`{portable_path(info.scenario_path)}`\n\n```toml\n{text}\n```\n")


def status_markdown(end: RunEnd) -> str:
    return (f"# Run {end.status}\n\n"
            + _md_table([("status", end.status), ("message", end.message), ("steps done", end.steps_done)]))


def metrics_markdown(metrics: dict) -> str:
    """Metrics as a markdown table plus the exact JSON."""
    body = json.dumps(metrics, indent=2, sort_keys=True, default=_json_default)
    return (f"# Metrics\n\n{_md_table(sorted(metrics.items()), ('metric', 'value'))}\n\n"
            f"```json\n{body}\n```\n")
