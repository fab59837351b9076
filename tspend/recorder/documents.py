"""The run's markdown documents: run, scenario, status and metrics."""

from __future__ import annotations

import dataclasses

import json
from typing import Sequence

import numpy as np

from ..sinks import RunEnd, RunInfo


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


def run_markdown(info: RunInfo) -> str:
    """Markdown summary of the run's identity."""
    rows: list[tuple[str, object]] = [
        ("scenario", info.scenario_name), ("scenario file", info.scenario_path),
        ("seed", info.seed), ("tspend version", info.version), ("plant kind", info.plant_kind),
        ("order n", info.order), ("dt (s)", info.dt), ("duration (s)", info.duration),
        ("steps", info.steps),
        ("model inputs", ", ".join(i.name for i in info.model_inputs)),
        ("compensator inputs", ", ".join(i.name for i in info.compensator_inputs)),
        ("plant extras", ", ".join(info.extras)),
    ]
    if info.drawing is not None:
        rows += [(f"plant: {k}", v) for k, v in dataclasses.asdict(info.drawing).items()]
    return f"# Run: {info.scenario_name}\n\n" + _md_table(rows)


def scenario_markdown(info: RunInfo) -> str:
    return f"# Scenario `{info.scenario_name}`\n\n`{info.scenario_path}`\n\n```toml\n{info.scenario_text}\n```\n"


def status_markdown(end: RunEnd) -> str:
    return (f"# Run {end.status}\n\n"
            + _md_table([("status", end.status), ("message", end.message), ("steps done", end.steps_done)]))


def metrics_markdown(metrics: dict) -> str:
    """Metrics as a markdown table plus the exact JSON."""
    body = json.dumps(metrics, indent=2, sort_keys=True, default=_json_default)
    return (f"# Metrics\n\n{_md_table(sorted(metrics.items()), ('metric', 'value'))}\n\n"
            f"```json\n{body}\n```\n")
