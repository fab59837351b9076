"""One tspend command run as a reader would type it, for the evidence scripts that rerun a
page's own commands (machines_evidence.py, policy_evidence.py): its --metrics JSON back, or
the script stops with the command and the end of its stderr."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TSPEND = [sys.executable, "-m", "tspend.cli"]


def metrics_of(args: list[str], folder: Path) -> dict:
    """``tspend ARGS --metrics FOLDER/m.json`` from the repository's root; its metrics."""
    metrics = folder / "m.json"
    metrics.unlink(missing_ok=True)
    r = subprocess.run([*TSPEND, *args, "--metrics", str(metrics)], capture_output=True,
                       text=True, cwd=ROOT)
    if r.returncode != 0:
        raise SystemExit(f"tspend {' '.join(args)}: exit {r.returncode}: "
                         f"{r.stderr.strip()[-400:]}")
    return json.loads(metrics.read_text())
