"""A hostile user's sweep: over 400 bad inputs against every command and the Python API.

``run``, ``crosscheck``, ``list``, ``inspect``, ``sweep``, ``compare``, ``export``,
``figures``, ``tune``, plug-ins (``--controller file.py:Class``), the Python API, and,
when their modules are there (each is skipped with a printed note otherwise), the gym
environment (``gymnasium.make("tspend/<scenario>-v0")``), ``tspend.linearize`` and the
``policy`` controller kind.

Every case runs ``python -m tspend.cli ...`` in a fresh directory holding a user's
files: a recording ``K.rrd``, metrics ``K.json``, a read-only ``RO.json``, a scenario
``S.toml``, a model ``M.xml`` and notes.  Most cases also aim ``--out K.rrd --metrics
K.json`` at those files, so a rejected run that truncated one is caught.  Each case is
classified:

- clean: the expected exit status (2 for bad input) with exactly one line on stderr;
- traceback: a Python traceback anywhere in the output;
- hang: no exit within the time limit;
- files lost: a pre-existing file changed or vanished;
- stray files: ``MUJOCO_LOG.TXT``, a leftover partial file, or a file outside the case
  directory's ``runs/`` that the case did not ask for;
- internal error: exit status 70 (or a traceback), where bad input should exit 2;
- processes left: a process still running in the case directory 5 s after the command
  ended (a sweep's workers or fork server);
- a case of the Python API runs a snippet: a TspendError is one line and exit 2, any
  other exception an internal error.

    python benchmarks/hostile_inputs.py            # all cases, 2 at a time
    python benchmarks/hostile_inputs.py -k seed    # only cases whose name contains "seed"
    python benchmarks/hostile_inputs.py -k misbehaving,issue33,"API gym",run-timeout  # issue 33's

Issue 33's cases (``-k misbehaving,issue33,"API gym",run-timeout``): plug-ins that
misbehave at run time (raise, return NaN, a vector, a string or None, sleep, call
``sys.exit(0)``, write into ``obs.state``, print megabytes) on ``run``, ``sweep``, ``compare``
and ``tune``; a gym agent's bad actions and an agent writing into its observation; the
issue's own cases (a cross-check that compared nothing, contacts at q0, the Furuta's
saturated arm, a swing-up that never swings up, a control delay longer than the run, a CSV
export read by pandas).  A case with a ``check`` is clean when its exit status is the
documented one and what it left is right (the metrics' status and a recording, the
table's rows, the report's verdict).

Prints the figures (tried, clean exit 2, internal errors, files lost, processes left,
...) and every case that was not clean.  Exit status 1 if any traceback, internal error,
hang, lost file or process left was seen.
"""

from __future__ import annotations

import argparse
import hashlib
import importlib.util
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from short_mode import sized

ROOT = Path(__file__).resolve().parents[1]
TIMEOUT_S = 120.0

# -- the user's files --------------------------------------------------------------------
CONTROLLER = {
    "lambda": "[1.0, 2.0]", "Q": "[[10.0, 0.0], [0.0, 10.0]]", "eta": "0.5", "gamma": "0.3",
    "bspline_order": "3", "control_points": "9", "b_min": "0.1",
    "operating_point": '"fixed"', "x_o": "[0.0, 0.0]", "u_o": "0.0",
}
SETS = {
    "states": "[{terms = 5, lo = -6.0, hi = 6.0}, {terms = 5, lo = -6.0, hi = 6.0}]",
    "u": "{terms = 3, lo = -1400.0, hi = 1400.0}",
    "e_delta": "{terms = 5, lo = -48.0, hi = 48.0}",
    "x_norm": "{terms = 5, lo = 0.0, hi = 6.0}",
}
DUFFING = {
    "": {"description": '"a user scenario"'},
    "run": {"duration": "0.05", "dt": "0.001", "seed": "1"},
    "plant": {"kind": '"duffing"', "x0": "[0.3, 0.0]"},
    "reference": {"kind": '"sine"', "amplitude": "1.0", "omega": "1.0"},
    "disturbance": {"kind": '"square"', "amplitude": "0.1", "period": "6.28"},
    "controller": CONTROLLER,
    "controller.sets": SETS,
}
MUJOCO = {
    **DUFFING,
    "plant": {"kind": '"cartpole_mujoco"', "x0": "[0.1, 0.0]", "model": '"M.xml"'},
    "reference": {"kind": '"sine"', "amplitude": "0.1", "omega": "1.0"},
    "controller": {**CONTROLLER, "b_min": "0.001", "operating_point": '"state"',
                   "x_o": "[0.0, 0.0]"},
    "controller.sets": {**SETS, "states": "[{terms = 5, lo = -0.8, hi = 0.8}, "
                                          "{terms = 5, lo = -0.8, hi = 0.8}]",
                        "u": "{terms = 3, lo = -1000.0, hi = 1000.0}",
                        "e_delta": "{terms = 5, lo = -12.0, hi = 12.0}",
                        "x_norm": "{terms = 5, lo = 0.0, hi = 1.05}"},
}


def render(base: dict, **changes: str | None) -> str:
    """TOML text of ``base`` with ``section__key=raw`` changes (None deletes the key)."""
    tables = {s: dict(kv) for s, kv in base.items()}
    for dotted, raw in changes.items():
        section, _, key = dotted.rpartition("__")
        section = section.replace("_DOT_", ".")
        tables.setdefault(section, {})
        if raw is None:
            tables[section].pop(key, None)
        else:
            tables[section][key] = raw
    lines = [f"{k} = {v}" for k, v in tables.pop("", {}).items()]
    for section, kv in tables.items():
        lines.append(f"\n[{section}]")
        lines += [f"{k} = {v}" for k, v in kv.items()]
    return "\n".join(lines) + "\n"


def model_text(**attrs: str) -> str:
    text = (ROOT / "models" / "cartpole.xml").read_text()
    for old, new in attrs.items():
        text = text.replace(old, new)
    return text


def make_user_files(d: Path) -> None:
    (d / "K.rrd").write_bytes(b"RRF2" + os.urandom(300_000))   # stands for a past recording
    (d / "K.json").write_text('{"rmse": 0.01}\n')
    (d / "RO.json").write_text('{"keep": true}\n')
    os.chmod(d / "RO.json", 0o444)
    (d / "notes.txt").write_text("my notes\n")
    (d / "S.toml").write_text(render(DUFFING))
    (d / "P.toml").write_text(render(MUJOCO))
    (d / "M.xml").write_text(model_text())
    (d / "sub").mkdir()
    (d / "sub" / "keep.rrd").write_bytes(b"RRF2" + os.urandom(1000))
    (d / "Other.parquet").write_bytes(OTHER_EMPTY_PARQUET)   # 0 rows, another schema
    (d / "Rows.parquet").write_bytes(OTHER_ROWS_PARQUET)     # 3 rows, another schema
    (d / "junk.parquet").write_bytes(os.urandom(5000))
    (d / "Plug.py").write_text(PLUGIN)


def _parquet(frame_columns: dict) -> bytes:
    import io

    import pandas as pd

    buf = io.BytesIO()
    pd.DataFrame(frame_columns).to_parquet(buf, index=False)
    return buf.getvalue()


try:
    OTHER_EMPTY_PARQUET = _parquet({"a": [], "b": []})
    OTHER_ROWS_PARQUET = _parquet({"a": [1, 2, 3], "b": ["x", "y", "z"]})
except ImportError:  # no pandas: plain bytes stand in
    OTHER_EMPTY_PARQUET = OTHER_ROWS_PARQUET = b"PAR1" + b"\x00" * 64 + b"PAR1"

#: a user's plug-in file: one good controller and several broken ones
PLUGIN = """
import sys
import time

import numpy as np
from tspend.controllers.base import Controller


class Zero(Controller):
    kind = "zero_force"

    def __init__(self, scenario):
        self.order = len(scenario.plant.x0)
        self.diagnostics = ()
        self.diag = np.zeros(0)

    def reset(self, rng):
        pass

    def step(self, obs, dt):
        return 0.0


class Raises(Zero):
    kind = "raises"

    def __init__(self, scenario):
        raise ValueError("this controller refuses to be built")


class NotAController:
    pass


NOT_A_CLASS = 5


# misbehaving at run time, each in its own way (issue 33)
class StepRaises(Zero):
    kind = "step_raises"

    def step(self, obs, dt):
        raise RuntimeError("a bug of mine")


class StepNaN(Zero):
    kind = "step_nan"

    def step(self, obs, dt):
        return float("nan")


class StepVector(Zero):
    kind = "step_vector"

    def step(self, obs, dt):
        return np.zeros(3)


class StepString(Zero):
    kind = "step_string"

    def step(self, obs, dt):
        return "push"


class StepNone(Zero):
    kind = "step_none"

    def step(self, obs, dt):
        return None


class StepSleeps(Zero):
    kind = "step_sleeps"

    def step(self, obs, dt):
        time.sleep(1000)
        return 0.0


class StepExits(Zero):
    kind = "step_exits"

    def step(self, obs, dt):
        sys.exit(0)


class StepMutates(Zero):
    kind = "step_mutates"

    def step(self, obs, dt):
        obs.state[0] = 1e9
        return 0.0


class StepGeneratorExit(Zero):
    kind = "step_generator_exit"

    def step(self, obs, dt):
        raise GeneratorExit("closed")


class StepCancelled(Zero):
    kind = "step_cancelled"

    def step(self, obs, dt):
        import asyncio
        raise asyncio.CancelledError("cancelled")


class MyBase(BaseException):
    pass


class StepOwnBase(Zero):
    kind = "step_own_base"

    def step(self, obs, dt):
        raise MyBase("mine")


class StepOsExit(Zero):
    kind = "step_os_exit"

    def step(self, obs, dt):
        import os
        os._exit(0)


# failing before the first sample, each in its own way (issue 51, item 14)
class InitOwnBase(Zero):
    def __init__(self, scenario):
        raise MyBase("built wrong")


class InitExits(Zero):
    def __init__(self, scenario):
        sys.exit(0)


class ResetRaises(Zero):
    def reset(self, rng):
        raise RuntimeError("reset broke")


class ResetOwnBase(Zero):
    def reset(self, rng):
        raise MyBase("reset broke")


class StepKeyboardInterrupt(Zero):
    def step(self, obs, dt):
        raise KeyboardInterrupt


class StepPrints(Zero):
    kind = "step_prints"

    def step(self, obs, dt):
        if obs.t < 0.0015:
            sys.stdout.write("x" * 4_000_000 + "\\n")  # megabytes on the user's stdout
        return 0.0
"""


def snapshot(d: Path) -> dict[str, str]:
    out = {}
    for p in d.rglob("*"):
        if p.is_file() and not p.is_symlink():
            out[str(p.relative_to(d))] = _digest(p)
    return out


def _digest(p: Path) -> str:
    st = p.stat()
    if st.st_size > 50_000_000:  # the sparse 8 GB files: size and time stand for content
        return f"{st.st_size}:{st.st_mtime_ns}"
    return hashlib.sha256(p.read_bytes()).hexdigest()


# -- the cases ---------------------------------------------------------------------------
@dataclass
class Case:
    name: str
    argv: list[str]
    expect: int = 2
    files: dict[str, str | bytes] = field(default_factory=dict)   # extra files to create
    setup: str = ""            # a named setup step (see prepare())
    send: tuple[int, float] | None = None   # (signal, seconds after start)
    head: bool = False         # read one line of stdout, then close it
    may_write: tuple[str, ...] = ()          # new files the case is allowed to leave
    twin: list[str] | None = None            # a second command started at the same time
    api: str = ""              # a Python snippet run instead of the CLI
    needs: str = ""            # a module the case needs (skipped with a note if absent)
    #: a named check of what the command left (see CHECKS); with it, the exit status and
    #: the check make the case clean (a sweep's progress lines on stderr are no error)
    check: str = ""
    #: environment variables for the command ("{d}" stands for the case's directory)
    env: dict[str, str] = field(default_factory=dict)


OUT = ["--out", "K.rrd", "--metrics", "K.json"]
RUN = ["run", "S.toml", "--duration", "0.05"]
MJ = ["run", "P.toml", "--duration", "0.05"]


def cases() -> list[Case]:
    cs: list[Case] = []

    def add(name, argv, expect=2, **kw):
        cs.append(Case(name, argv, expect, **kw))

    def file_case(name, text, expect=2, base_argv=None, **kw):
        files = {"X.toml": text}
        files.update(kw.pop("files", {}))
        add(name, (base_argv or ["run", "X.toml"]) + OUT, expect, files=files, **kw)

    # scenario values, through the file
    bad_values = {
        "run__duration": ["0", "-1", "nan", "inf", "1e308", '"10"', "true", "[1.0]"],
        "run__dt": ["0", "-0.001", "nan", "1e-300", "1.0", '"x"'],
        "run__seed": ["-1", "1.5", '"7"', "1" * 5000, str(2**64), "[1]"],
        "run__snapshot_every": ["1e308", "-1", "nan", "1e-9", "inf"],
        "run__control_bound": ["-1", "nan"],
        "plant__kind": ['"quantum"', "3", '""'],
        "plant__x0": ["[1.0]", "[nan, 0.0]", '["a", 0.0]', "[" + ", ".join(["0.0"] * 3000) + "]",
                      "1.0"],
        "plant__state_bound": ["-1", "nan"],
        "reference__kind": ['"square"', "1"],
        "reference__amplitude": ["nan", '"big"', "inf"],
        "disturbance__period": ["0", "-1", "nan"],
        "controller__lambda": ["[-1.0, 2.0]", "[1e308, 1e308]", "[1.0]", "[]", "[nan, 1.0]"],
        "controller__Q": ["[[1.0, 2.0], [0.0, 1.0]]", "[[-1.0, 0.0], [0.0, 1.0]]", "[[1.0]]",
                          "[[nan, 0.0], [0.0, 1.0]]", "7"],
        "controller__eta": ["0", "-1", "nan", '"fast"'],
        "controller__gamma": ["0", "inf"],
        "controller__bspline_order": ["1", "1000", str(10**18), "0"],
        "controller__control_points": ["1000000", "0", "2", str(2**63)],
        "controller__b_min": ["0", "-1"],
        "controller__adaptation": ['"third"', "2"],
        "controller__operating_point": ['"moving"'],
        "controller__x_o": ["[0.0]", "[inf, 0.0]"],
        "controller__bogus_key": ["1"],
        "controller_DOT_sets__u": ["{terms = 10000000000000000000, lo = -1.0, hi = 1.0}",
                                   "{terms = 0, lo = -1.0, hi = 1.0}",
                                   "{terms = 3, lo = 1.0, hi = -1.0}",
                                   "{terms = 3, lo = nan, hi = 1.0}", "5",
                                   "{terms = 3, lo = -1.0}"],
        "controller_DOT_sets__states": [
            "[{terms = 51, lo = -1.0, hi = 1.0}, {terms = 5, lo = -1.0, hi = 1.0}]",
            "[{terms = 2000, lo = -1.0, hi = 1.0}, {terms = 2000, lo = -1.0, hi = 1.0}]",
            "[{terms = 3, lo = -1.0, hi = 1.0}]", "[1, 2]"],
        "__name": ['"a\\u0000b"', '"\\u001b[31mred"', '""', '"' + "n" * 5000 + '"', "5"],
        "__description": ['"bell\\u0007"', "[1]"],
        "__extra": ["1"],
    }
    for key, values in bad_values.items():
        for i, raw in enumerate(values):
            file_case(f"file {key.replace('_DOT_', '.')} #{i}", render(DUFFING, **{key: raw}))
    file_case("file missing [controller]", render(DUFFING, controller__lambda=None).replace(
        "[controller]\n", "[ctrl]\n"))
    file_case("file missing [plant]", render(DUFFING).replace("[plant]", "[plantx]"))
    file_case("file dt above duration", render(DUFFING, run__dt="0.1", run__duration="0.05"))
    file_case("file 3e9 steps", render(DUFFING, run__dt="1e-6", run__duration="3000"))
    file_case("file nested arrays 100k", "x = " + "[" * 100_000 + "]" * 100_000 + "\n")
    file_case("file nested tables 100k", "x = " + "{a = " * 100_000 + "1" + "}" * 100_000 + "\n")
    file_case("file nested arrays 40", render(DUFFING, __extra="[" * 40 + "]" * 40))
    file_case("file not TOML", "this is not [toml\n")
    file_case("file binary", b"\x00\xff\xfe" * 1000)
    file_case("file empty", "")
    file_case("file table as value", render(DUFFING).replace("[run]", "run = 5\n[runx]"))
    file_case("file unicode name runs, escaped", render(DUFFING, __name='"\\u202eevil"'),
              expect=0, may_write=("K.rrd", "K.json"))
    add("file 8 GB sparse", ["run", "Big.toml"] + OUT, setup="big_scenario")
    add("scenario is a directory", ["run", "Dir.toml"] + OUT, setup="dir_scenario")
    add("scenario is a FIFO", ["run", "F.toml"] + OUT, setup="fifo_scenario")
    add("scenario missing", ["run", "nope"] + OUT)
    add("scenario name 5000 chars", ["run", "s" * 5000] + OUT)
    add("scenario path traversal", ["run", "../../../../etc/passwd"] + OUT)
    # names that run, sanitised: the default recording stays in runs/
    for i, nm in enumerate(['"../../escape"', '"/tmp/abs"', '"a/b\\\\c"', '"..."', '"   "']):
        add(f"odd name runs #{i}", ["run", "X.toml"], expect=0,
            files={"X.toml": render(DUFFING, __name=nm)}, may_write=("runs/",))

    # MuJoCo models
    mj_models = {
        "timestep 0": model_text(**{'timestep="0.001"': 'timestep="0"'}),
        "timestep nan": model_text(**{'timestep="0.001"': 'timestep="nan"'}),
        "timestep -1": model_text(**{'timestep="0.001"': 'timestep="-1"'}),
        "timestep inf": model_text(**{'timestep="0.001"': 'timestep="inf"'}),
        "timestep text": model_text(**{'timestep="0.001"': 'timestep="fast"'}),
        "timestep 0.0015": model_text(**{'timestep="0.001"': 'timestep="0.0015"'}),
        "not XML": "<mujoco><worldbody>",
        "empty": "",
        "binary": "\x00\x01\x02",
        "no hinge": model_text(**{'name="hinge"': 'name="hinge2"'}),
        "no slider": model_text(**{'name="slider"': 'name="slide2"'}),
        "no actuator": model_text(**{'name="force"': 'name="push"'}),
        "integrator bogus": model_text(**{'integrator="RK4"': 'integrator="magic"'}),
        "motor on the hinge": model_text(**{'joint="slider" gear': 'joint="hinge" gear'}),
        "hinge is a slide": model_text(**{'name="hinge" type="hinge"': 'name="hinge" type="slide"'}),
    }
    for label, text in mj_models.items():
        add(f"MJCF {label}", ["run", "Q.toml", "--duration", "0.05"] + OUT,
            files={"Q.toml": render(MUJOCO, plant__model='"Q.xml"'), "Q.xml": text})
    # gravity is the model's own unless plant.g overrides it: a NaN in the file is bad input
    add("MJCF gravity nan", ["run", "Q.toml", "--duration", "0.05"] + OUT,
        files={"Q.toml": render(MUJOCO, plant__model='"Q.xml"'),
               "Q.xml": model_text(**{'gravity="0 0 -9.8"': 'gravity="0 0 nan"'})})
    add("MJCF missing", MJ + ["--set", 'plant.model="none.xml"'] + OUT)
    add("MJCF is a directory", MJ + ["--set", 'plant.model="sub"'] + OUT)
    add("MJCF 8 GB sparse", MJ + ["--set", 'plant.model="Big.xml"'] + OUT, setup="big_model")
    # (0 is no bad value here: on cartpole_mujoco it keeps the model's own number)
    for label, value in {"M -1e-300": "-1e-300", "M nan": "nan", "M -1": "-1.0", "l -1": "-1.0",
                         "g -1": "-1.0", "m inf": "inf"}.items():
        key = label.split()[0]
        add(f"MJCF plant.{label}", MJ + ["--set", f"plant.{key}={value}"] + OUT)
    # a finite but absurd machine is a valid input: balancing, the task check refuses it
    # (the reference needs 5e291 N of its 2000 N motor); without a fall to avoid, the loop
    # diverges at once (exit 3) and the recording of that is kept
    add("MJCF plant.M 1e308 cannot balance", MJ + ["--set", "plant.M=1e308"] + OUT)
    add("MJCF plant.M 1e308 diverges", MJ + ["--set", "plant.M=1e308", "--set",
                                            "task.fall_angle=0.0"] + OUT, expect=3,
        may_write=("K.rrd", "K.json"))
    add("dt not a multiple of the timestep", MJ + ["--set", "run.dt=0.0015"] + OUT)
    add("joint names swapped", MJ + ["--set", 'plant.slide_joint="hinge"',
                                     "--set", 'plant.hinge_joint="slider"'] + OUT)
    add("actuator unknown", MJ + ["--set", 'plant.actuator="push"'] + OUT)
    add("integrator unknown", MJ + ["--set", 'plant.integrator="magic"'] + OUT)

    # command-line values
    for v in ["-5", "nan", "inf", "0", "1e308", "abc", "", "1e-300", "-inf"]:
        add(f"--duration {v[:12]}", ["run", "S.toml", f"--duration={v}"] + OUT)
    for v in ["1" * 5000, "-1", str(2**64), "1.5", "abc", "", "0x10"]:
        add(f"--seed {v[:12]}", RUN + [f"--seed={v}"] + OUT)
    for v in ["0", "-1", "1" * 40, "abc", "1.5"]:
        add(f"--record-every {v[:12]}", RUN + [f"--record-every={v}"] + OUT)
    add("--backend bogus", RUN + ["--backend", "fortran"] + OUT)
    add("--controller bogus", RUN + ["--controller", "pid9000"] + OUT)
    add("--controller help", RUN + ["--controller", "help"] + OUT, expect=0)
    for v in ["rerun+http://127.0.0.1:70000/proxy", "rerun+http://127.0.0.1:abc/proxy",
              "not a url", "ftp://x:1/", "rerun+http://[::1/proxy", "rerun+http://:9876/proxy",
              "rerun+http://127.0.0.1:99999999999999999999/proxy"]:
        add(f"--connect {v[:30]}", RUN + ["--connect", v] + OUT)
    sets = {
        "no equals": "controller.eta", "empty key": "=1", "newline trailing": "run.seed=1\nrun.dt=5",
        "newline table": "run.seed=1\n[plant]\nkind='nonaffine'", "CR": "run.seed=1\rx",
        "deep value": "controller.eta=" + "[" * 50_000 + "]" * 50_000,  # argv limit: 128 kB
        "deep value 40": "controller.eta=" + "[" * 40 + "1" + "]" * 40,
        "deep key": "controller." + ".".join(["a"] * 200) + "=1",
        "dots": "controller..eta=1", "unknown key": "controller.etta=1",
        "unknown table": "nothing.here=1", "seed 5000 digits": "run.seed=" + "9" * 5000,
        "terms 10**18": "controller.sets.u={terms=1000000000000000000, lo=-1.0, hi=1.0}",
        "control_points 1e6": "controller.control_points=1000000",
        "snapshot_every 1e308": "run.snapshot_every=1e308",
        "name NUL": 'name="a\\u0000b"', "name escape": 'name="\\u001b]0;pwned\\u0007"',
        "name 300": 'name="' + "x" * 300 + '"',
        "table into scalar": "run.duration.x=1", "scalar into table": "run=5",
        "NUL in value": "run.seed=1\x00", "huge float": "controller.eta=1e999",
        "string for number": "controller.eta=fast", "list for number": "controller.eta=[1,2]",
        "3 million rules": "controller.sets.states=[{terms=1732, lo=-1.0, hi=1.0}, "
                           "{terms=1732, lo=-1.0, hi=1.0}]",
        "u terms 51": "controller.sets.u={terms=51, lo=-1.0, hi=1.0}",

        "order 100": "controller.bspline_order=100",
        "sum of sines 5000": "reference={kind='sum_of_sines', amplitudes=[" +
                             ",".join(["1.0"] * 5000) + "], omegas=[1.0], phases=[0.0]}",
        "reference kind": "reference.kind=wobble", "dt 1e-300": "run.dt=1e-300",
        "duration 1e308": "run.duration=1e308",
    }
    for label, item in sets.items():
        if "\x00" in item:
            continue  # argv cannot carry a NUL byte
        add(f"--set {label}", RUN + ["--set", item] + OUT)

    # outputs aimed at inputs, at each other, at things that are not files
    outs = {
        "out = metrics": ["--out", "K.rrd", "--metrics", "K.rrd"],
        "metrics = out json": ["--out", "X.json", "--metrics", "K.json"],
        "out = scenario": ["--out", "S.toml"],
        "metrics = scenario": ["--metrics", "S.toml"],
        "out = model": ["--out", "M.xml"],
        "out = notes": ["--out", "notes.txt"],
        "out symlink to scenario": ["--out", "link.rrd"],
        "metrics hard link to scenario": ["--metrics", "hard.json"],
        "out /dev/full": ["--out", "/dev/full"],
        "out /dev/null": ["--out", "/dev/null"],
        "metrics /dev/full": ["--metrics", "/dev/full"],
        "metrics /proc": ["--metrics", "/proc/self/status"],
        "metrics /proc json": ["--metrics", "/proc/x.json"],
        "out /proc": ["--out", "/proc/1/x.rrd"],
        "out directory": ["--out", "sub"],
        "out directory.rrd": ["--out", "dir.rrd"],
        "out read-only": ["--out", "RO.rrd"],
        "metrics read-only": ["--metrics", "RO.json"],
        "out 300-char name": ["--out", "x" * 296 + ".rrd"],
        "metrics 300-char name": ["--metrics", "m" * 295 + ".json"],
        "out path 5000": ["--out", "/".join(["d" * 200] * 25) + "/x.rrd"],
        "out directory name 300": ["--out", "d" * 300 + "/x.rrd"],
        "metrics directory name 300": ["--metrics", "d" * 300 + "/x.json"],
        "out empty": ["--out", ""],
        "metrics empty": ["--metrics", ""],
        "out under a file": ["--out", "notes.txt/x.rrd"],
        "out no suffix": ["--out", "K"],
        "metrics .txt": ["--metrics", "m.txt"],
        "out in read-only dir": ["--out", "rodir/x.rrd"],
        "out control chars": ["--out", "a\x1b[2Jb.txt"],
        "out FIFO": ["--out", "fifo.rrd"],
        "out socket-ish /dev/stdout": ["--out", "/dev/stdout"],
        "metrics /dev/stdout": ["--metrics", "/dev/stdout"],
    }
    root = os.geteuid() == 0  # root writes into a mode 555 directory: that run is fine
    for label, argv in outs.items():
        ok = root and label == "out in read-only dir"
        add(f"outputs: {label}", ["run", "S.toml", "--duration", "0.05"] + argv, setup="links",
            expect=0 if ok else 2, may_write=("rodir/",) if ok else ())
    add("outputs: partial in use", ["run", "S.toml", "--duration", "0.05", "--out", "K.rrd"],
        setup="locked_partial")

    # crosscheck
    CC = ["crosscheck", "P.toml", "--duration", "0.05", "--no-record"]
    for v in ["-5", "nan", "1e9", "0", "inf", "abc", "1e-9"]:
        add(f"crosscheck --open-loop-duration {v}", CC + ["--open-loop-duration", v,
                                                          "--json", "K.json"])
    for v in ["-1", "nan", "0", "inf", "x"]:
        add(f"crosscheck --tol {v}", CC + ["--tol", v, "--json", "K.json"])
    add("crosscheck not a cart-pole", ["crosscheck", "S.toml", "--duration", "0.05", "--json",
                                       "K.json", "--out", "K.rrd"])
    add("crosscheck json = scenario", CC + ["--json", "P.toml"])
    add("crosscheck json = model", CC + ["--json", "M.xml"])
    add("crosscheck out = json", ["crosscheck", "P.toml", "--duration", "0.05", "--json",
                                  "K.json", "--out", "K.json"])
    add("crosscheck json /dev/full", CC + ["--json", "/dev/full"])
    add("crosscheck MJCF timestep 0", ["crosscheck", "Q.toml", "--duration", "0.05",
                                       "--no-record", "--json", "K.json"],
        files={"Q.toml": render(MUJOCO, plant__model='"Q.xml"'),
               "Q.xml": model_text(**{'timestep="0.001"': 'timestep="0"'})})
    for label, text in mj_models.items():
        add(f"crosscheck MJCF {label}", ["crosscheck", "Q.toml", "--duration", "0.05",
                                         "--json", "K.json", "--out", "K.rrd"],
            files={"Q.toml": render(MUJOCO, plant__model='"Q.xml"'), "Q.xml": text})
    for label in ("newline trailing", "deep key", "terms 10**18", "name escape",
                  "snapshot_every 1e308", "dt 1e-300"):
        add(f"crosscheck --set {label}", CC + ["--set", sets[label], "--json", "K.json"])
    add("crosscheck seed huge", CC + ["--seed", "9" * 5000])
    add("crosscheck --set newline", CC + ["--set", "run.seed=1\nx=2"])
    add("crosscheck --connect port", CC[:-1] + ["--connect", "rerun+http://h:65536/proxy"])

    # list and the command line itself
    add("list | head -1", ["list"], expect=0, head=True)
    add("list extra argument", ["list", "extra"])
    add("list bogus option", ["list", "--bogus"])
    add("no command", [])
    add("unknown command", ["fly"])
    add("run bogus option", RUN + ["--frobnicate"] + OUT)
    add("run two scenarios", ["run", "S.toml", "P.toml"] + OUT)
    add("out and no-record", RUN + ["--out", "K.rrd", "--no-record"])

    # signals in start-up: nothing written, the documented status, one line
    for sig, status in ((signal.SIGINT, 130), (signal.SIGTERM, 143), (signal.SIGHUP, 129)):
        for delay in (0.3, 0.8):
            add(f"{signal.Signals(sig).name} at {delay} s",
                ["run", "P.toml", "--duration", "20"] + OUT, expect=status,
                send=(sig, delay), may_write=("K.rrd", "K.json"))
    more_cases(add, sets, mj_models)
    return cs


# -- the commands added since: sweep, compare, export, inspect, figures, tune, plug-ins,
#    the Python API, the gym environment, linearize and the policy kind -------------------
SW = ["sweep", "ex3_pendulum_ode", "--duration", "0.05", "--seeds", "0:2", "--jobs", "1"]
CMP = ["compare", "ex3_pendulum_ode", "--duration", "0.05", "--seeds", "0:3", "--jobs", "1",
       "--controller", "lqr,pd", "--resamples", "200"]
TUNE = ["tune", "ex3_pendulum_ode", "--controller", "lqr", "--trials", "2", "--seeds", "0:2",
        "--duration", "0.05", "--jobs", "1", "--out", "tuned.toml"]
API_PRELUDE = """
import sys, warnings
warnings.simplefilter("ignore")
try:
    import tspend
    from tspend.runtime.errors import TspendError
    S = lambda: tspend.load_scenario("ex3_pendulum_ode")
except Exception as exc:
    print("tspend could not be imported:", exc, file=sys.stderr); sys.exit(70)
try:
    exec(compile(sys.argv[1], "<case>", "exec"))
except TspendError as exc:
    print("tspend: error:", " ".join(str(exc).split()), file=sys.stderr); sys.exit(2)
except Exception as exc:
    # gymnasium's own error for an id nobody registered is a clean answer too
    if type(exc).__module__.startswith("gymnasium.error") and "make(" in sys.argv[1]:
        print("gymnasium: error:", " ".join(str(exc).split()), file=sys.stderr); sys.exit(2)
    if isinstance(exc, ModuleNotFoundError) and ("tspend" in str(exc) or "gymnasium" in str(exc)):
        print("skipped:", exc, file=sys.stderr); sys.exit(77)
    raise
sys.exit(0)
"""


def more_cases(add, sets: dict, mj_models: dict) -> None:
    # -- sweep: values
    for v in ["10:3", "a", "-1", "0:10000000", "0:" + "9" * 40, "1,,2", "1.5", "", "0:0",
              "1,-2", "9" * 5000, "0:99999999999999999999"]:
        add(f"sweep --seeds #{len(v)} {v[:20]}", SW[:4] + ["--seeds", v, "--out", "new.parquet"])
    for v in ["0", "-1", "999", "abc", "1e9", "100000000000000000000"]:
        add(f"sweep --jobs {v[:20]}", SW[:6] + ["--jobs", v, "--out", "new.parquet"])
    for v in ["::::", "tcp://127.0.0.1:0", "tcp://[::1:x", "tcp://host:99999999999999",
              "x" * 5000, "tcp://", "inproc://", "tcp://127.0.0.1:1"]:
        add(f"sweep --dask {v[:24]}", SW + ["--dask", v, "--out", "new.parquet"])
    grids = ["controller.eta=0.1,-1", "controller.eta=", "=1,2", "run.seed=1,2",
             "controller.eta=" + "[" * 5000 + "]" * 5000, "nothing.here=1",
             "controller.etta=1", "plant.model=none.xml", "run.dt=nan",
             "controller." + ".".join(["a"] * 200) + "=1", "run.duration=1 x=2",
             "controller.eta=1e999", "run.dt=0.001,0.001,[",
             "controller.eta=" + ",".join(["0.1"] * 1000001)[:100000]]
    for i, g in enumerate(grids):
        add(f"sweep --grid #{i} {g[:24]}", SW + ["--grid", g, "--out", "new.parquet"])
    add("sweep --grid too many runs", SW + ["--grid", "controller.eta=" + ",".join(
        str(0.01 * k + 0.01) for k in range(2000)), "--grid", "plant.x0=" + ",".join(
        f"[0.{k}, 0.0]" for k in range(1, 10)), "--seeds", "0:100", "--out", "new.parquet"])
    for label in ("newline trailing", "newline table", "deep value 40", "deep key", "dots",
                  "unknown key", "unknown table", "seed 5000 digits", "terms 10**18",
                  "name escape", "table into scalar", "scalar into table", "huge float",
                  "string for number", "3 million rules", "order 100", "sum of sines 5000",
                  "dt 1e-300", "duration 1e308"):
        add(f"sweep --set {label}", SW + ["--set", sets[label], "--out", "new.parquet"])
    add("sweep --set trailing TOML", SW + ["--set", "run.duration=1 x=2", "--out", "new.parquet"])
    add("sweep --set trailing table", SW + ["--set", "run.duration=1 [plant]",
                                            "--out", "new.parquet"])
    for v in ["nan", "-1", "0", "inf", "abc"]:
        add(f"sweep --duration {v}", SW[:2] + ["--duration", v, "--out", "new.parquet"])
    add("sweep --record bogus", SW + ["--record", "some", "--out", "new.parquet"])
    add("sweep --controller bogus", SW + ["--controller", "pid9000", "--out", "new.parquet"])
    add("sweep --controller empty", SW + ["--controller", ",", "--out", "new.parquet"])
    add("sweep scenario missing", ["sweep", "nope", "--out", "new.parquet"])
    add("sweep scenario broken", ["sweep", "X.toml", "--seeds", "0:2", "--out", "new.parquet"],
        files={"X.toml": "this is not [toml\n"})
    for label, text in mj_models.items():
        if label.startswith("timestep 0.0015"):
            continue
        add(f"sweep MJCF {label}", ["sweep", "Q.toml", "--seeds", "0:2", "--duration", "0.05",
                                    "--jobs", "1", "--out", "new.parquet"],
            files={"Q.toml": render(MUJOCO, plant__model='"Q.xml"'), "Q.xml": text})
    add("sweep MJCF missing", SW[:2] + ["--set", 'plant.model="none.xml"', "--seeds", "0:2",
                                        "--out", "new.parquet"], files={})
    # the table and its journal
    outs = {
        "0-row Parquet of another schema": "Other.parquet",
        "Parquet of another schema": "Rows.parquet",
        "random bytes": "junk.parquet",
        "the scenario": "S.toml",
        "the model": "M.xml",
        "a recording": "K.rrd",
        "notes": "notes.txt",
        "a directory": "sub",
        "/dev/full": "/dev/full",
        "/proc": "/proc/self/status",
        "empty": "",
        "under a file": "notes.txt/x.parquet",
    }
    for label, target in outs.items():
        add(f"sweep --out {label}", SW + ["--out", target])
        add(f"compare --out {label}", CMP + ["--out", target])
    add("sweep journal is a symlink", SW + ["--out", "J.parquet"], setup="journal_symlink")
    add("sweep journal corrupt", SW + ["--out", "C.parquet"], setup="journal_corrupt")
    add("sweep journal of another table", SW + ["--out", "O.parquet"], setup="journal_other")
    add("sweep journal hard link", SW + ["--out", "H.parquet"], setup="journal_hardlink")
    add("sweep table locked", SW + ["--out", "L.parquet"], setup="table_locked")
    add("sweep runs, nothing stray", SW + ["--out", "new.parquet"], expect=0,
        may_write=("new.parquet",))
    add("sweep two on one table", ["sweep", "ex3_pendulum_ode", "--duration", "0.05", "--seeds",
                                   "0:3", "--jobs", "1", "--out", "two.parquet"],
        expect=-2, twin=["sweep", "ex3_pendulum_ode", "--duration", "0.05", "--seeds", "3:6",
                         "--jobs", "1", "--out", "two.parquet"], may_write=("two.parquet",))
    add("sweep SIGKILL, workers end", ["sweep", "pendulum_mujoco", "--jobs", "2", "--seeds",
                                       "0:400", "--out", "k.parquet"],
        expect=-9, send=(signal.SIGKILL, 12.0), may_write=("k.parquet",))
    # -- compare
    for v in ["0", "99", "-1", "10000000000", "abc"]:
        add(f"compare --resamples {v}", CMP[:-2] + ["--resamples", v])
    for v in ["3:1", "a", "0:10000000"]:
        add(f"compare --seeds {v}", CMP[:4] + ["--seeds", v] + CMP[6:])
    add("compare one kind", CMP[:8] + ["--controller", "lqr"] + CMP[10:])
    add("compare kind bogus", CMP[:8] + ["--controller", "lqr,nope"] + CMP[10:])
    add("compare --metric bogus", CMP + ["--metric", "speed"])
    add("compare --jobs 999", CMP[:6] + ["--jobs", "999"] + CMP[8:])
    add("compare --dask bad", CMP + ["--dask", "::::"])
    add("compare --tune 0", CMP + ["--tune", "0"])
    add("compare --tune huge", CMP + ["--tune", "1000000000"])
    add("compare --tune-seeds overlap", CMP + ["--tune", "1", "--tune-seeds", "0:2"])
    add("compare --stats-seed -1", CMP + ["--stats-seed", "-1"])
    add("compare --set trailing", CMP + ["--set", "run.dt=0.001\nx=1"])
    add("compare --set deep key", CMP + ["--set", sets["deep key"]])
    add("compare broken model", ["compare", "Q.toml", "--seeds", "0:2", "--controller", "lqr,pd",
                                 "--jobs", "1"],
        files={"Q.toml": render(MUJOCO, plant__model='"Q.xml"'),
               "Q.xml": model_text(**{'name="hinge"': 'name="hinge2"'})})
    for label, target in {"scenario": "S.toml", "model": "M.xml", "read-only": "RO.json",
                          "directory": "sub", "/dev/full": "/dev/full", "not json": "x.txt",
                          "under a file": "notes.txt/x.json"}.items():
        add(f"compare --metrics {label}", CMP + ["--metrics", target])
    # -- export
    add("export random bytes", ["export", "R.rrd", "--to", "x.csv"],
        files={"R.rrd": os.urandom(20000)})
    add("export corrupt recording", ["export", "K.rrd", "--to", "x.csv"])
    add("export empty file", ["export", "E.rrd", "--to", "x.parquet"], files={"E.rrd": b""})
    add("export missing", ["export", "none.rrd", "--to", "x.csv"])
    add("export a directory", ["export", "sub", "--to", "x.csv"])
    add("export a scenario", ["export", "S.toml", "--to", "x.csv"])
    add("export to existing", ["export", "sub/keep.rrd", "--to", "notes.csv"],
        files={"notes.csv": "a,b\n1,2\n"})
    add("export to .txt", ["export", "K.rrd", "--to", "x.txt"])
    add("export to a directory", ["export", "K.rrd", "--to", "sub"])
    add("export to .rrd", ["export", "sub/keep.rrd", "--to", "K.rrd"])
    add("export to /dev/full", ["export", "K.rrd", "--to", "/dev/full"])
    add("export to under a file", ["export", "K.rrd", "--to", "notes.txt/x.csv"])
    add("export to a long name", ["export", "K.rrd", "--to", "x" * 300 + ".csv"])
    add("export a FIFO", ["export", "fifo.rrd", "--to", "x.csv"], setup="links")
    # -- inspect
    for v in ["nan", "-1", "0", "inf", "abc", "1e-300x"]:
        add(f"inspect --dt {v}", ["inspect", "M.xml", "--dt", v])
    for label, text in mj_models.items():
        if label in ("timestep 0.0015", "integrator bogus", "motor on the hinge"):
            continue
        # inspect finds the joints by type: other names are a model it reads (and replaces
        # the --json file with a complete one)
        # (a hinge made a slide is a chain of two slides: the articulated domain reads it)
        renamed = label in ("no hinge", "no actuator", "hinge is a slide")
        add(f"inspect MJCF {label}", ["inspect", "Q.xml", "--metrics", "K.json"], files={"Q.xml": text},
            expect=0 if renamed else 2, may_write=("K.json",) if renamed else ())
    add("inspect heightfield 10^10 cells", ["inspect", "Q.xml"], files={"Q.xml": model_text(
        **{"<worldbody>": '<asset><hfield name="h" nrow="100000" ncol="100000" '
                          'size="1 1 1 1"/></asset><worldbody>'})})
    add("inspect 20000 bodies", ["inspect", "Q.xml"], files={
        "Q.xml": "<mujoco><worldbody>" + "".join(f'<body name="b{i}"><geom size=".1"/></body>'
                                                 for i in range(20000)) + "</worldbody></mujoco>"})
    add("inspect 8 GB sparse", ["inspect", "Big.xml"], setup="big_model")
    add("inspect missing", ["inspect", "none.xml"])
    add("inspect a directory", ["inspect", "sub"])
    add("inspect a scenario", ["inspect", "S.toml"])
    add("inspect --json scenario", ["inspect", "M.xml", "--json", "S.toml"])
    add("inspect --json read-only", ["inspect", "M.xml", "--json", "RO.json"])
    add("inspect --json directory", ["inspect", "M.xml", "--json", "sub"])
    add("inspect --slide bogus", ["inspect", "M.xml", "--slide", "nope"])
    add("inspect --actuator bogus", ["inspect", "M.xml", "--actuator", "nope"])
    add("inspect runs, no MUJOCO_LOG", ["inspect", "Q.xml", "--dt", "0.01"], expect=0,
        files={"Q.xml": model_text(**{'timestep="0.001"': 'timestep="0.0010"'})})
    # -- figures
    add("figures box random bytes", ["figures", "box", "junk.parquet", "--out", "figs"])
    add("figures box other schema", ["figures", "box", "Rows.parquet", "--out", "figs"])
    add("figures box 0 rows", ["figures", "box", "Other.parquet", "--out", "figs"])
    add("figures box missing", ["figures", "box", "none.parquet", "--out", "figs"])
    add("figures box metric bogus", ["figures", "box", "Rows.parquet", "--metrics", "speed"])
    add("figures heatmap other schema", ["figures", "heatmap", "Rows.parquet", "--x", "a",
                                         "--y", "b", "--out", "figs"])
    add("figures --out a file", ["figures", "box", "Rows.parquet", "--out", "notes.txt"])
    add("figures paper --duration nan", ["figures", "paper", "--duration", "nan", "--out", "figs"])
    add("figures paper --every 0", ["figures", "paper", "--every", "0", "--out", "figs"])
    add("figures paper --seed -1", ["figures", "paper", "--seed", "-1", "--out", "figs"])
    add("figures bogus", ["figures", "pie"])
    # -- tune
    for v in ["0", "-1", "1000000000", "abc"]:
        add(f"tune --trials {v}", TUNE[:4] + ["--trials", v] + TUNE[6:])
    for v in ["3:1", "a", "0:10000000"]:
        add(f"tune --seeds {v}", TUNE[:6] + ["--seeds", v] + TUNE[8:])
    add("tune --test-seeds overlap", TUNE + ["--test-seeds", "1:3"])
    add("tune --metric bogus", TUNE + ["--metric", "speed"])
    add("tune --controller bogus", TUNE[:2] + ["--controller", "nope"] + TUNE[4:])
    add("tune --controller a plug-in", TUNE[:2] + ["--controller", "Plug.py:Zero"] + TUNE[4:])
    add("tune --out scenario", TUNE[:-2] + ["--out", "S.toml"])
    add("tune --out user file", TUNE[:-2] + ["--out", "P.toml"])
    add("tune --out not toml", TUNE[:-2] + ["--out", "x.txt"])
    add("tune --out directory", TUNE[:-2] + ["--out", "sub"])
    add("tune --storage bad URL", TUNE + ["--storage", "nosuchdb://x/y"])
    add("tune --storage directory", TUNE + ["--storage", "sub"])
    add("tune --jobs 999", TUNE[:10] + ["--jobs", "999"] + TUNE[12:])
    add("tune --dask bad", TUNE[:10] + TUNE[12:] + ["--dask", "::::"])
    add("tune --duration nan", TUNE[:8] + ["--duration", "nan"] + TUNE[10:])
    add("tune --set trailing", TUNE + ["--set", "run.dt=0.001\nx=1"])
    add("tune --set deep key", TUNE + ["--set", sets["deep key"]])
    add("tune broken model", ["tune", "Q.toml", "--controller", "lqr", "--trials", "2", "--seeds",
                              "0:2", "--jobs", "1", "--out", "tuned.toml"],
        files={"Q.toml": render(MUJOCO, plant__model='"Q.xml"'),
               "Q.xml": model_text(**{'name="hinge"': 'name="hinge2"'})})
    # -- plug-ins, on every command that takes --controller
    plugs = {"missing file": "none.py:Zero", "missing class": "Plug.py:Nope",
             "not a controller": "Plug.py:NotAController", "not a class": "Plug.py:NOT_A_CLASS",
             "constructor raises": "Plug.py:Raises", "syntax error": "Bad.py:Zero",
             "a directory": "sub:Zero", "no module": "no_such_module.x:Zero",
             "empty class": "Plug.py:", "a scenario": "S.toml:Zero"}
    files = {"Bad.py": "def (:\n"}
    for label, spec in plugs.items():
        add(f"plugin run {label}", RUN + ["--controller", spec] + OUT, files=files)
        add(f"plugin sweep {label}", SW + ["--controller", spec, "--out", "new.parquet"],
            files=files)
        add(f"plugin compare {label}", CMP[:8] + ["--controller", f"lqr,{spec}"] + CMP[10:],
            files=files)
    add("plugin runs", ["run", "ex3_pendulum_ode", "--duration", "0.05", "--no-record",
                        "--controller", "Plug.py:Zero"], expect=0)
    # -- the Python API
    api = {
        "run controller nope": 'tspend.run(S(), controller="nope")',
        "load no such scenario": 'tspend.load_scenario("no_such_scenario")',
        "load None": "tspend.load_scenario(None)",
        "load 5": "tspend.load_scenario(5)",
        "override bad key": 'tspend.override(S(), **{"controller.etta": 1})',
        "override bad value": 'tspend.override(S(), **{"run.dt": "x"})',
        "override nan": 'tspend.override(S(), **{"run.dt": float("nan")})',
        "override object": 'tspend.override(S(), **{"run.dt": object()})',
        "override not a scenario": 'tspend.override(None, **{"run.dt": 1})',
        "override long key": 'tspend.override(S(), **{"controller." + "a" * 100000: 1})',
        "override deep key": 'tspend.override(S(), **{".".join(["a"] * 20000): 1})',
        "override deep value": 'v = []\nfor _ in range(5000):\n    v = [v]\n'
                               'tspend.override(S(), **{"controller.eta": v})',
        "run seed -1": "tspend.run(S(), seed=-1)",
        "run seed str": 'tspend.run(S(), seed="a")',
        "run duration nan": 'tspend.run(S(), duration=float("nan"))',
        "run overrides list": "tspend.run(S(), overrides=[1, 2])",
        "run scenario 5": "tspend.run(5)",
        "run controller 5": "tspend.run(S(), controller=5)",
        "run unknown option": "tspend.run(S(), bogus=1)",
        "run plant_kind bogus": 'tspend.run(S(), plant_kind="quantum")',
        "run block_size 0": "tspend.run(S(), block_size=0, duration=0.1)",
        "build_plant None": "tspend.build_plant(None)",
        "build_controller kind": 'tspend.build_controller(S(), kind="nope")',
        "sweep seeds huge": "tspend.sweep(S(), seeds=range(10**8))",
        "sweep grid list": "tspend.sweep(S(), grid=[1])",
        "sweep jobs 999": "tspend.sweep(S(), jobs=999)",
        "sweep dask bad": 'tspend.sweep(S(), dask="::::")',
        "sweep controllers 5": "tspend.sweep(S(), controllers=5)",
        "sweep out other schema": 'tspend.sweep(S(), seeds=[0], out="Other.parquet")',
        "read_table junk": 'tspend.sweep.read_table("junk.parquet")',
    }
    for label, code in api.items():
        add(f"API {label}", [], api=code)
    misbehaving_cases(add)
    issue44_cases(add)
    issue44a_cases(add)  # issue 44, part A
    issue51_cases(add)
    # -- guarded: modules other work is adding (skipped with a note when absent)
    gym = {
        "gym unknown scenario": 'import tspend.gym, gymnasium; gymnasium.make("tspend/nope-v0")',
        "gym bad override": 'import tspend.gym, gymnasium; gymnasium.make('
                            '"tspend/ex3_pendulum_ode-v0", overrides={"run.dt": "x"})',
        "gym bad controller option": 'import tspend.gym, gymnasium; gymnasium.make('
                                     '"tspend/ex3_pendulum_ode-v0", overrides={"nothing.here": 1})',
        "gym step nan": 'import tspend.gym, gymnasium, numpy as np\n'
                        'env = gymnasium.make("tspend/ex3_pendulum_ode-v0")\n'
                        'env.reset(seed=0)\nenv.step(np.array([np.nan], dtype=np.float32))',
        "gym step wrong shape": 'import tspend.gym, gymnasium, numpy as np\n'
                                'env = gymnasium.make("tspend/ex3_pendulum_ode-v0")\n'
                                'env.reset(seed=0)\nenv.step(np.zeros(7))',
        "gym reset seed -1": 'import tspend.gym, gymnasium\n'
                             'env = gymnasium.make("tspend/ex3_pendulum_ode-v0")\n'
                             'env.reset(seed=-1)',
    }
    for label, code in gym.items():
        add(f"API {label}", [], api=code, needs="tspend.gym")
    lin = {
        "linearize unknown scenario": 'tspend.linearize("no_such_scenario")',
        "linearize at wrong length": 'tspend.linearize("ex3_pendulum_ode", at=[0.0])',
        "linearize at nan": 'tspend.linearize("ex3_pendulum_ode", at=[float("nan"), 0.0])',
        "linearize not a scenario": "tspend.linearize(5)",
        "linearize at a string": 'tspend.linearize("pendulum_mujoco", at="up")',
    }
    for label, code in lin.items():
        add(f"API {label}", [], api=code, needs="tspend.linearize")
    for label, value in {"missing": '"none.onnx"', "not onnx": '"notes.txt"',
                         "random bytes": '"R.onnx"', "a directory": '"sub"', "a number": "5",
                         "empty": '""'}.items():
        add(f"policy path {label}", ["run", "ex3_pendulum_ode", "--duration", "0.05",
                                     "--controller", "policy", "--set",
                                     f"controllers.policy.path={value}"] + OUT,
            files={"R.onnx": os.urandom(3000)}, needs="tspend.controllers.policy")
        add(f"policy sweep path {label}", SW + ["--controller", "policy", "--set",
                                                 f"controllers.policy.path={value}",
                                                 "--out", "new.parquet"],
            files={"R.onnx": os.urandom(3000)}, needs="tspend.controllers.policy")


#: each misbehaving plug-in class: (label, class, the run's status, its exit status)
MISBEHAVING = [("raises", "StepRaises", "controller_error", 6),
               ("returns NaN", "StepNaN", "diverged", 3),
               ("returns a vector", "StepVector", "controller_error", 6),
               ("returns a string", "StepString", "controller_error", 6),
               ("returns None", "StepNone", "controller_error", 6),
               ("sleeps", "StepSleeps", "timeout", 7),
               ("calls sys.exit(0)", "StepExits", "controller_error", 6),
               ("raises GeneratorExit", "StepGeneratorExit", "controller_error", 6),
               ("raises CancelledError", "StepCancelled", "controller_error", 6),
               ("raises its own BaseException", "StepOwnBase", "controller_error", 6),
               ("mutates obs.state", "StepMutates", "controller_error", 6),
               ("prints 4 MB", "StepPrints", "completed", 0)]
TOUCHING = str(ROOT / "tests" / "models" / "cartpole_touching_rails.xml")
#: a snippet's own verdict: exit 1 with a line saying what was wrong (not a traceback)
FAIL = "import sys\ndef fail(why):\n    print('not as documented:', why, file=sys.stderr); sys.exit(1)\n"


# -- issue 44, part A (i44a): its hostile inputs, a block of their own ---------------------
DOUBLE_ON_CART = str(ROOT / "tests" / "models" / "gymnasium_double_pendulum_ranges.xml")


def issue44a_cases(add) -> None:
    """Issue 44 part A: a slide named as a pole, another machine's model given to a kind,
    plant.integrator on the articulated and Furuta machines, gym reward weights that would
    pay for ending early.  Each is exit 2 with one line."""
    quick = ["--duration", "0.05"] + OUT
    add("issue44a slide as a pole", ["run", "double_cartpole_mujoco", "--set",
                                     'plant.poles=["slider"]'] + quick)
    add("issue44a cart-pole kind on a double pendulum",
        ["run", "pendulum_mujoco", "--set", f'plant.model="{DOUBLE_ON_CART}"', "--set",
         'plant.actuator="slide"'] + quick)
    add("issue44a furuta kind on a double pendulum",
        ["run", "furuta_mujoco", "--set", f'plant.model="{DOUBLE_ON_CART}"', "--set",
         'plant.actuator="slide"'] + quick)
    for kind in ("double_cartpole_mujoco", "furuta_mujoco", "acrobot_ode"):
        for value in ('"RK5"', "4", '"rk4"'):
            add(f"issue44a {kind} plant.integrator={value}",
                ["run", kind, "--set", f"plant.integrator={value}"] + quick)
    for label, weights in (("alive 0", '{"alive": 0.0}'), ("alive -1", '{"alive": -1.0}'),
                           ("alive nan", '{"alive": float("nan")}'),
                           ("control -1", '{"control": -1.0}'),
                           ("tracking negative", '{"tracking": (1.0, -1.0)}'),
                           ("tracking a string", '{"tracking": "x"}'),
                           ("unknown key", '{"alvie": 1.0}'), ("a list", "[1.0]")):
        add(f"issue44a API gym reward {label}", [], needs="tspend.gym", api=(
            "import tspend.gym\n"
            f"tspend.gym.TspendEnv('ex3_pendulum_ode', reward={weights})"))
# -- end of issue 44, part A --------------------------------------------------------------


def misbehaving_cases(add) -> None:
    """Issue 33: runs that claim no more than happened, and user code that cannot break
    the testbed: misbehaving plug-ins on run, sweep, compare and tune, a gym agent's bad
    actions, and the issue's own cases."""
    quick = ["ex3_pendulum_ode", "--duration", "0.05"]
    for label, cls, status, code in MISBEHAVING:
        spec = f"Plug.py:{cls}"
        if cls == "StepSleeps":
            # a run has no time limit of its own: Ctrl-C / SIGTERM ends it, outputs kept
            add(f"misbehaving run {label}, SIGTERM at 30 s", ["run", *quick, "--controller", spec]
                + OUT, 143, send=(signal.SIGTERM, 30.0), may_write=("K.",),
                check="metrics:interrupted")
        else:
            add(f"misbehaving run {label}", ["run", *quick, "--controller", spec] + OUT,
                code,
                may_write=("K.",), check=f"metrics:{status}")
        limit = ["--run-timeout", "5"] if cls == "StepSleeps" else []
        # a run that did not complete (a controller's error, a timeout): "not every run
        # completed", exit 7 (issue 44)
        incomplete = 7 if status in ("controller_error", "timeout") else 0
        add(f"misbehaving sweep {label}", SW + ["--controller", spec, "--out", "new.parquet",
                                                "--record", "none"] + limit,
            incomplete, may_write=("new.",), check=f"rows:{status}")
        add(f"misbehaving compare {label}", CMP[:8] + ["--controller", f"lqr,{spec}"] + CMP[10:]
            + limit, incomplete, check="compared")
        add(f"misbehaving tune {label}", TUNE[:2] + ["--controller", spec] + TUNE[4:])
    for command, base in (("sweep", SW), ("compare", CMP), ("tune", TUNE)):
        for value in ("0", "-5", "nan", "inf", "1e12", "soon"):
            add(f"{command} --run-timeout {value}", base + ["--run-timeout", value])
    gym = {
        "string": '"left"', "None": "None", "inf": 'float("inf")', "a dict": '{"u": 1.0}',
    }
    for label, action in gym.items():
        add(f"API gym step {label}", [], needs="tspend.gym", api=(
            "import tspend.gym, gymnasium\n"
            "env = gymnasium.make('tspend/ex3_pendulum_ode-v0')\n"
            f"env.reset(seed=0)\nenv.step({action})"))
    add("API gym step 1e300 is clipped", [], expect=0, needs="tspend.gym", api=FAIL + (
        "import tspend.gym, gymnasium\n"
        "env = gymnasium.make('tspend/ex3_pendulum_ode-v0')\n"
        "env.reset(seed=0)\n_, _, _, _, info = env.step([1e300])\n"
        "hi = float(env.unwrapped.action_space.high[0])\n"
        "if not abs(info['u']) <= max(hi, abs(env.unwrapped.u_range[1])): fail(info['u'])\n"))
    add("API gym agent mutates the observation", [], expect=0, needs="tspend.gym", api=FAIL + (
        "import tspend.gym, gymnasium, numpy as np\n"
        "def trace(mutate):\n"
        "    env = gymnasium.make('tspend/ex3_pendulum_ode-v0')\n"
        "    obs, _ = env.reset(seed=0)\n"
        "    for _ in range(20):\n"
        "        if mutate:\n"
        "            obs[:] = 1e9\n"
        "            try:\n"
        "                env.unwrapped.controller_observation().state[0] = 1e9\n"
        "            except (ValueError, TypeError):\n"
        "                pass\n"
        "        obs, *_ = env.step(np.zeros(1, dtype=np.float32))\n"
        "    return obs\n"
        "if not np.array_equal(trace(False), trace(True)): fail('the agent changed the plant')\n"))
    # the issue's own cases
    add("issue33 crosscheck of a model touching its rails at t = 0",
        ["crosscheck", "pendulum_mujoco", "--set", f"plant.model={TOUCHING!r}".replace("'", '"'),
         "--set", "run.duration=1", "--no-record", "--json", "K.json"], 1,
        may_write=("K.",), check="inconclusive")
    add("issue33 inspect names the contacts at q0", ["inspect", TOUCHING, "--json", "K.json"], 0,
        may_write=("K.",), check="contacts")
    add("issue33 furuta_mujoco second_type", ["run", "furuta_mujoco", "--controller",
                                              "second_type", "--duration", "3"] + OUT, 4,
        may_write=("K.",), check="metrics:joint_limit")
    add("issue33 furuta_swingup lqr", ["run", "furuta_swingup", "--controller", "lqr",
                                       "--duration", "3", "--set", "task.goal_by=2"] + OUT, 4,
        may_write=("K.",), check="metrics:not_reached")
    add("issue33 control_delay longer than the run", ["run", *quick, "--set",
                                                      "run.control_delay=5000"] + OUT)
    add("issue33 export CSV read by pandas", [], expect=0, may_write=("x.",), api=FAIL + (
        "import subprocess, pandas\n"
        "for argv in (['run', 'ex3_pendulum_ode', '--duration', '0.05', '--out', 'x.rrd'],\n"
        "             ['export', 'x.rrd', '--out', 'x.csv']):\n"
        "    r = subprocess.run([sys.executable, '-m', 'tspend.cli', *argv], capture_output=True)\n"
        "    if r.returncode: fail(f'{argv[0]} exit {r.returncode}')\n"
        "try:\n"
        "    frame = pandas.read_csv('x.csv')\n"
        "except Exception as exc:\n"
        "    fail(f'pandas.read_csv: {type(exc).__name__}: {exc}')\n"
        "if list(frame.columns[:2]) != ['t_s', 'hinge_rad'] or 'u_N' not in frame: "
        "fail(list(frame.columns))\n"))


# -- issue 44: interrupted solves, plan files, failed runs in sweeps, caches, bounds,
#    commands that must not replace a user's files, stray files, exports ----------------
ONE_HINGE = """<mujoco model="one hinge">
  <option timestep="0.001"/>
  <worldbody>
    <body name="link1">
      <joint name="hinge" type="hinge" axis="0 1 0" damping="0.05"/>
      <inertial pos="0 0 -0.5" mass="1" diaginertia="0.02 0.02 0.001"/>
    </body>
  </worldbody>
  <actuator><motor name="motor" joint="hinge" gear="1" ctrlrange="-5 5" ctrllimited="true"/></actuator>
</mujoco>
"""


def _record_csv(model_text: str, joints: tuple[str, ...], seconds: float) -> str:
    """A record MuJoCo simulates open loop under a multisine (what identify reads)."""
    import numpy as np
    import mujoco

    m = mujoco.MjModel.from_xml_string(model_text)
    d = mujoco.MjData(m)
    n = int(round(seconds / m.opt.timestep))
    t = np.arange(n) * m.opt.timestep
    u = 2.0 * np.sin(2 * np.pi * np.multiply.outer(t, [0.5, 1.3, 2.9])).sum(1)
    q = np.empty((n, len(joints)))
    adr = [m.joint(j).qposadr[0] for j in joints]
    for i in range(n):
        q[i] = d.qpos[adr]
        d.ctrl[0] = u[i]
        mujoco.mj_step(m, d)
    cols = {"t_s": t, **{f"{j}_{'m' if j == 'slider' else 'rad'}": q[:, k]
                        for k, j in enumerate(joints)}, "u": u}
    lines = [",".join(cols)] + [",".join(repr(float(v[i])) for v in cols.values())
                                for i in range(n)]
    return "\n".join(lines) + "\n"


def _plan_file(**change) -> bytes:
    """A plan for swingup_mujoco's states on its 1 ms step, with ``change`` made to it."""
    import numpy as np

    from tspend.controllers.trajectory import Plan, write_plan

    n, dt = 6, 0.001
    fields = dict(t=dt * np.arange(n), states=np.zeros((n, 4)), u=np.zeros(n),
                  state_names=("slider", "hinge", "slider_dot", "hinge_dot"),
                  state_units=("m", "rad", "m/s", "rad/s"), u_name="force", u_unit="N",
                  dt=dt, interval=0.002)
    fields.update(change)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "p.parquet"
        write_plan(Plan(**fields), path)
        return path.read_bytes()


#: one warm cache (a derived acrobot, MPC's compiled solver), made once, copied per case
_WARM: dict[str, Path] = {}
_WARM_LOCK = __import__("threading").Lock()
ARTICULATED_RUN = ["run", "acrobot_mujoco", "--duration", "0.01", "--no-record"]
MPC_RUN = ["run", "pendulum_mujoco", "--controller", "mpc", "--duration", "0.02", "--no-record"]


def _warm_cache(base: Path) -> Path:
    with _WARM_LOCK:
        if "cache" not in _WARM:
            folder = base / "warm-cache"
            env = dict(os.environ, TSPEND_CACHE_DIR=str(folder))
            for argv in (ARTICULATED_RUN, MPC_RUN):
                subprocess.run([sys.executable, "-m", "tspend.cli", *argv], cwd=base, env=env,
                               capture_output=True, timeout=600)
            _WARM["cache"] = folder
        return _WARM["cache"]


def _damage_cache(d: Path, base: Path, damage: str) -> None:
    """Copy the warm cache into the case's ``cache/`` and damage one entry as ``damage``."""
    warm = _warm_cache(base)
    shutil.copytree(warm, d / "cache")
    modules = sorted((d / "cache" / "articulated").glob("tspend_articulated_*.py"))
    pycache = d / "cache" / "articulated" / "__pycache__"
    for module in modules if damage.startswith("module") else ():
        if damage == "module garbage":
            module.write_bytes(os.urandom(3000))
        elif damage == "module empty":
            module.write_bytes(b"")
        elif damage == "module truncated":
            module.write_bytes(module.read_bytes()[: module.stat().st_size // 2])
        elif damage == "module a directory":
            module.unlink()
            module.mkdir()
        elif damage == "module of another machine":
            # another machine's derivation (three joints) under this key, stamped as its own
            text = module.read_text().replace("NV = 2", "NV = 3")
            body = text.rsplit("# tspend-cache", 1)[0]
            digest = hashlib.sha256(body.encode()).hexdigest()
            module.write_text(f"{body}# tspend-cache key={'f' * 24} sha256={digest}\n")
    if damage == "numba code swapped":
        # another function's code over the dynamics' (issue 51: a segfault before)
        for target in pycache.glob("*.dynamics-*.nbc"):   # each module's, from its rhs
            module = target.name.split(".dynamics-")[0]
            for other in pycache.glob(f"{module}.rhs-*.nbc"):
                shutil.copyfile(other, target)
    if damage == "numba code truncated":
        for f in sorted(pycache.glob("*.nbc")):
            f.write_bytes(f.read_bytes()[:100])
    elif damage == "numba index truncated":
        for f in sorted(pycache.glob("*.nbi")):
            f.write_bytes(f.read_bytes()[:10])
    elif damage == "mpc so corrupted":
        for f in (d / "cache" / "mpc").glob("*.so"):
            f.write_bytes(b"\x7fELF" + os.urandom(4000))


def issue44_cases(add) -> None:
    """Issue 44 (part B): every command honours an interrupt, solves included; plan files
    are checked on load; failed runs make a sweep or comparison incomplete; a plug-in's
    BaseException is its error and os._exit leaves no visible partial file; caches are
    checked and rebuilt; every size and physical value is bounded at load; identify and
    excite replace nothing of the user's and leave nothing behind."""
    plan = ["plan", "double_cartpole_swingup", "--out", "p.parquet"]
    mine = {"p.parquet": b"PAR1 the user's own plan"}
    for sig, status in ((signal.SIGINT, 130), (signal.SIGTERM, 143), (signal.SIGHUP, 129)):
        add(f"issue44 plan {signal.Signals(sig).name} at 3 s", plan, status, files=mine,
            send=(sig, 3.0))
    add("issue44 plan SIGINT at 6 s", plan, 130, files=mine, send=(signal.SIGINT, 6.0))
    # plan files
    import numpy as np

    bad_plans = {
        "t backwards": dict(t=0.001 * np.arange(6)[::-1]),
        "NaN in u": dict(u=np.array([0.0, 1.0, np.nan, 0.0, 0.0, 0.0])),
        "inf in a state": dict(states=np.full((6, 4), np.inf)),
        "0 rows": dict(t=np.zeros(0), states=np.zeros((0, 4)), u=np.zeros(0)),
        "1 row": dict(t=np.zeros(1), states=np.zeros((1, 4)), u=np.zeros(1)),
    }
    for label, change in bad_plans.items():
        add(f"issue44 plan file {label}", ["run", "swingup_mujoco", "--controller", "tvlqr",
                                           "--duration", "0.05", "--set",
                                           'controllers.tvlqr.plan="bad.parquet"'] + OUT,
            files={"bad.parquet": _plan_file(**change)})
    add("issue44 plan file junk", ["run", "swingup_mujoco", "--controller", "tvlqr", "--set",
                                   'controllers.tvlqr.plan="junk.parquet"'] + OUT)
    # a plug-in that ends its own process: nothing visible of the outputs it had
    add("issue44 plug-in os._exit(0) in run", ["run", "ex3_pendulum_ode", "--duration", "0.05",
                                              "--controller", "Plug.py:StepOsExit"] + OUT, 0,
        may_write=(".K.",))
    add("issue44 plug-in os._exit(0) in sweep", SW + ["--controller", "Plug.py:StepOsExit",
                                                      "--out", "new.parquet", "--record", "none"],
        7, may_write=("new.", ".new."), check="rows:failed")
    # caches: damaged entries are rebuilt with one line saying so
    for damage in ("module garbage", "module empty", "module truncated", "module a directory",
                   "module of another machine", "numba code truncated", "numba index truncated"):
        add(f"issue44 cache {damage}", ARTICULATED_RUN, 0, setup=f"cache:{damage}",
            env={"TSPEND_CACHE_DIR": "{d}/cache"}, may_write=("cache/",), check="said:rebuilt")
    add("issue44 cache mpc so corrupted", MPC_RUN, 0, setup="cache:mpc so corrupted",
        env={"TSPEND_CACHE_DIR": "{d}/cache"}, may_write=("cache/",), check="said:rebuilt")
    add("issue44 cache not writable", ARTICULATED_RUN, 0, setup="tmp",
        env={"TSPEND_CACHE_DIR": "{d}/notes.txt/cache", "TMPDIR": "{d}/tmp"},
        check="empty:tmp")
    # bounds on what sizes work
    for label, value in (("horizon 2000 s", "controllers.tvlqr.horizon=2000"),
                         ("horizon 1e6 s", "controllers.tvlqr.horizon=1e6"),
                         ("step 1e-9", "controllers.tvlqr.step=1e-9"),
                         ("interval 1e6", "controllers.tvlqr.interval=1e6")):
        add(f"issue44 plan {label}", plan + ["--set", value], files=mine)
    for label, value in (("horizon 1000000", "controllers.mpc.horizon=1000000"),
                         ("substeps 100000", "controllers.mpc.substeps=100000")):
        add(f"issue44 mpc {label}", ["run", "pendulum_mujoco", "--controller", "mpc",
                                     "--duration", "0.05", "--set", value] + OUT)
    cartpole = model_text()
    record = {"R.csv": _record_csv(cartpole, ("hinge", "slider"), 1.0),
              "cal.xml": "<!-- the user's calibration -->\n", "fit.json": '{"mine": 1}\n',
              "fig.png": b"\x89PNG the user's figure"}
    ident = ["identify", "R.csv", "--model", "M.xml", "--params", "m", "--out", "cal.xml",
             "--metrics", "fit.json"]
    for label, extra in (("--segment 1e-9", ["--segment", "1e-9"]),
                         ("--bootstrap 1e9", ["--uncertainty", "bootstrap", "--bootstrap",
                                              "1000000000"]),
                         ("--seed -1", ["--seed", "-1"]),
                         ("--fix M=-5", ["--fix", "M=-5"]),
                         ("--fix gear=0", ["--fix", "gear=0"]),
                         ("--validation 1e-6 --figure", ["--validation", "1e-6", "--segment",
                                                         "0.3", "--figure", "fig.png"])):
        add(f"issue44 identify {label}", ident + extra, files=record)
    one = {"one.csv": _record_csv(ONE_HINGE, ("hinge",), 3.0), "One.xml": ONE_HINGE,
           **{k: v for k, v in record.items() if k != "R.csv"}}
    add("issue44 identify --figure on a one-hinge model", [
        "identify", "one.csv", "--model", "One.xml", "--params", "link1.mass", "--segment",
        "0.5", "--out", "cal.xml", "--metrics", "fit.json", "--figure", "fig.png"], 0,
        files=one, may_write=("cal.xml", "fit.json", "fig.png"), check="png:fig.png")
    add("issue44 excite --f-max 1e6", ["excite", "pendulum_mujoco", "--out", "x.toml",
                                       "--f-max", "1e6"])
    add("issue44 excite --f-max above half the input's rate",
        ["excite", "pendulum_mujoco", "--out", "x.toml", "--f-max", "600"])
    add("issue44 excite keeps a user's .x.toml.check.toml", ["excite", "pendulum_mujoco",
                                                             "--out", "x.toml"], 0,
        files={".x.toml.check.toml": "the user's own\n"}, may_write=("x.toml",))
    add("issue44 excite ex2_duffing", ["excite", "ex2_duffing", "--out", "x.toml"], 0,
        may_write=("x.toml",), check="notsaid:trial.toml")
    # physical values of an MJCF
    for label, old, new in (("infinite pole mass", 'mass="1"', 'mass="inf"'),
                            ("infinite cart mass", 'mass="10"', 'mass="inf"'),
                            ("negative pole mass", 'mass="1"', 'mass="-5"'),
                            ("infinite inertia", 'diaginertia="1 1 1"', 'diaginertia="inf 1 1"')):
        files = {"Q.toml": render(MUJOCO, plant__model='"Q.xml"'),
                 "Q.xml": model_text(**{old: new})}
        add(f"issue44 MJCF {label}", ["run", "Q.toml", "--duration", "0.05"] + OUT, files=files)
        add(f"issue44 MJCF {label}, inspect", ["inspect", "Q.xml", "--json", "K.json"],
            files=files)
    # every recording a run leaves can be exported
    add("issue44 export a run that failed at its first sample", [], expect=0,
        may_write=("x.",), api=FAIL + (
            "import subprocess, pandas\n"
            "r = subprocess.run([sys.executable, '-m', 'tspend.cli', 'run', 'ex3_pendulum_ode',\n"
            "                    '--duration', '0.05', '--controller', 'Plug.py:StepRaises',\n"
            "                    '--out', 'x.rrd'], capture_output=True)\n"
            "if r.returncode != 6: fail(f'run exit {r.returncode}')\n"
            "r = subprocess.run([sys.executable, '-m', 'tspend.cli', 'export', 'x.rrd', '--out',\n"
            "                    'x.csv'], capture_output=True, text=True)\n"
            "if r.returncode: fail(f'export exit {r.returncode}: {r.stderr.strip()}')\n"
            "frame = pandas.read_csv('x.csv')\n"
            "if len(frame) or list(frame.columns[:2]) != ['t_s', 'hinge_rad']: "
            "fail(list(frame.columns))\n"))


# -- issue 51: hostile input and faults (items 12-17, 19, 20) -------------------------------
def _slide_pole_model() -> str:
    """models/double_cartpole.xml with hinge2 made a slide (issue 51, item 20)."""
    text = (ROOT / "models" / "double_cartpole.xml").read_text()
    return text.replace('name="hinge2" type="hinge"', 'name="hinge2" type="slide"')


def _under_8gb(argv: list[str], phrase: str) -> str:
    """An API case: ``tspend ARGV`` under an 8 GB address limit ends 2 with one line
    holding ``phrase`` (the warp lines of mujoco-mjx aside, issue 51 item 5)."""
    return FAIL + (
        "import resource, subprocess\n"
        "limit = lambda: resource.setrlimit(resource.RLIMIT_AS, (8 << 30, 8 << 30))\n"
        f"r = subprocess.run([sys.executable, '-m', 'tspend.cli', *{argv!r}],\n"
        "                   capture_output=True, text=True, preexec_fn=limit)\n"
        "lines = [l for l in r.stderr.splitlines() if l.strip() and 'warp' not in l]\n"
        f"if r.returncode != 2 or len(lines) != 1 or {phrase!r} not in lines[0]:\n"
        "    fail(f'exit {r.returncode}: {lines[-3:]}')\n")


def issue51_cases(add) -> None:
    """Issue 51's hostile inputs and faults, each as the issue ran it: show of a file
    naming another by a relative path and into a full stdout (12); signals in the first
    second of every command (13: a race a test cannot pin, so here); plug-ins failing before
    their first sample (14); the mpsc plan period (15); mjx sizes and devices (16); caches
    swapped, on a full file system, garbage in identify's .so (17); options a backend
    would ignore, a sweep interrupted before its first row, gym actions that are strings,
    check_claims without its page (19); a pole made a slide (20)."""
    # 12
    add("issue51 show of an excite experiment", [], 0, may_write=("exp.toml",), api=FAIL + (
        "import subprocess\n"
        "cli = [sys.executable, '-m', 'tspend.cli']\n"
        "r = subprocess.run([*cli, 'excite', 'pendulum_mujoco', '--out', 'exp.toml'],\n"
        "                   capture_output=True, text=True)\n"
        "if r.returncode: fail(f'excite exit {r.returncode}')\n"
        "r = subprocess.run([*cli, 'show', 'exp.toml'], capture_output=True, text=True)\n"
        "if r.returncode: fail(f'show exit {r.returncode}: {r.stderr.strip()[-200:]}')\n"))
    add("issue51 show into /dev/full", [], 0, api=FAIL + (
        "import subprocess\n"
        "with open('/dev/full', 'w') as full:\n"
        "    r = subprocess.run([sys.executable, '-m', 'tspend.cli', 'show', 'pendulum_mujoco'],\n"
        "                       stdout=full, stderr=subprocess.PIPE, text=True)\n"
        "lines = r.stderr.strip().splitlines()\n"
        "if r.returncode != 5 or len(lines) != 1 or 'stdout could not be written' not in lines[0]:\n"
        "    fail(f'exit {r.returncode}: {lines[-2:]}')\n"))
    # 13: the issue's times, and later ones (under load the interpreter alone may take 0.5 s)
    plan = ["plan", "double_cartpole_swingup", "--nominal", "--out", "p.parquet"]
    mine = {"p.parquet": b"PAR1 the user's own plan"}
    for sig, status, at in ((signal.SIGINT, 130, 0.5), (signal.SIGTERM, 143, 0.6),
                            (signal.SIGHUP, 129, 0.6), (signal.SIGINT, 130, 1.0),
                            (signal.SIGTERM, 143, 1.5)):
        add(f"issue51 plan {signal.Signals(sig).name} at {at} s", plan, status, files=mine,
            send=(sig, at))
    for argv, sig, status in ((["run", "double_cartpole_mujoco"] + OUT, signal.SIGINT, 130),
                              (["crosscheck", "double_cartpole_mujoco"], signal.SIGTERM, 143),
                              (["sweep", "pendulum_mujoco", "--seeds", "0:2", "--out",
                                "s.parquet"], signal.SIGHUP, 129),
                              (["identify", "R.csv", "--model", "M.xml", "--params", "m"],
                               signal.SIGINT, 130)):
        add(f"issue51 {argv[0]} {signal.Signals(sig).name} at 0.6 s", argv, status,
            send=(sig, 0.6), files={"R.csv": _record_csv(model_text(), ("hinge", "slider"), 1.0)})
    # 14
    for cls, status in (("InitOwnBase", 2), ("InitExits", 2), ("ResetRaises", 6),
                        ("ResetOwnBase", 6)):
        add(f"issue51 plug-in {cls}", ["run", "ex3_pendulum_ode", "--duration", "0.05",
                                       "--controller", f"Plug.py:{cls}"] + OUT, status)
    for label, text in (("sys.exit(0)", "import sys\nsys.exit(0)\n"),
                        ("its own BaseException", "class Mine(BaseException):\n    pass\n\n\n"
                                                  "raise Mine('imported wrong')\n")):
        add(f"issue51 plug-in {label} at import", ["run", "ex3_pendulum_ode", "--duration",
                                                   "0.05", "--controller", "Bad.py:X"] + OUT,
            files={"Bad.py": text})
    add("issue51 plug-in raises KeyboardInterrupt itself",
        ["run", "ex3_pendulum_ode", "--duration", "0.05", "--controller",
         "Plug.py:StepKeyboardInterrupt"] + OUT, 6, may_write=("K.rrd", "K.json"),
        check="metrics:controller_error")
    # 15
    add("issue51 mpsc plan_period 1e-9", ["run", "pendulum_mujoco", "--safety", "mpsc", "--set",
                                          "safety.plan_period=1e-9"] + OUT)
    # 16 (the warp lines of mujoco-mjx are item 5's: the checks read the error line)
    mjx = ["sweep", "pendulum_mujoco", "--backend", "mjx", "--controller", "lqr"]
    add("issue51 mjx 1e6 seeds under 8 GB", [], 0, needs="mujoco.mjx",
        api=_under_8gb(mjx + ["--seeds", "0:1000000"], "GiB of memory"))
    add("issue51 mjx duration 1e5 under 8 GB", [], 0, needs="mujoco.mjx",
        api=_under_8gb(mjx + ["--seeds", "0:2", "--duration", "100000"], "GiB of memory"))
    add("issue51 mjx JAX_PLATFORMS=cuda without a GPU", mjx + ["--seeds", "0:2"], 2,
        needs="mujoco.mjx", env={"JAX_PLATFORMS": "cuda"}, check="said:JAX has no device")
    # 17
    add("issue51 cache numba code swapped", ARTICULATED_RUN, 0,
        setup="cache:numba code swapped", env={"TSPEND_CACHE_DIR": "{d}/cache"},
        may_write=("cache/",), check="said:replaced without its index")
    if hasattr(os, "geteuid") and os.geteuid() == 0:  # a full file system: a tmpfs, as root
        add("issue51 cache on a full file system", ARTICULATED_RUN, 0, setup="full_fs",
            env={"TSPEND_CACHE_DIR": "{d}/full/cache"}, may_write=("full/",))
    add("issue51 identify --jit garbage in its .so", IDENTIFY_JIT, 0,
        setup="identify_jit_garbage", env={"TSPEND_CACHE_DIR": "{d}/cache"},
        files={"R.csv": _record_csv(model_text(), ("hinge", "slider"), 1.0)},
        may_write=("cache/",), check="said:rebuilt")
    # 19
    add("issue51 sweep --precision float32 on cpu", SW + ["--precision", "float32"])
    add("issue51 sweep mjx --dask local", mjx + ["--seeds", "0:2", "--dask", "local"],
        needs="mujoco.mjx", check="said:--dask: the mjx backend")
    add("issue51 sweep mjx --run-timeout", mjx + ["--seeds", "0:2", "--run-timeout", "5"],
        needs="mujoco.mjx", check="said:--run-timeout: the mjx backend")
    for safety in ("cbf", "mpsc"):
        add(f"issue51 sweep mjx safety {safety} refused before the banner",
            mjx + ["--seeds", "0:2", "--set", f"safety.filter={safety}"], needs="mujoco.mjx",
            check="notsaid:sweep of")
    add("issue51 sweep interrupted before its first row", ["sweep", "double_cartpole_mujoco",
                                                           "--seeds", "0:2", "--out", "s.parquet"],
        130, send=(signal.SIGINT, 12.0), may_write=("s.parquet",), check="notsaid:0 rows kept")
    for label, action in (("string", '"0.5"'), ("bytes", 'b"1"')):
        add(f"issue51 API gym env.step({label})", [], needs="tspend.gym", api=(
            "from tspend.gym import TspendEnv\nenv = TspendEnv('pendulum_mujoco')\n"
            f"env.reset(seed=0)\nenv.step({action})\n"))
    add("issue51 check_claims without docs/results.md", [], 0, api=FAIL + (
        f"sys.path.insert(0, {str(ROOT / 'tools')!r})\nimport check_claims\n"
        "n, problems = check_claims.check_sections([('docs/none.md', '<!-- a -->', "
        "'<!-- b -->', lambda: '', 'x')])\n"
        "if not problems or 'missing' not in problems[0]: fail(problems)\n"))
    # 20
    slide = {"pole2_slide.xml": _slide_pole_model()}
    for controller in ("pd", "lqr"):
        add(f"issue51 pole made a slide, {controller}", [
            "run", "double_cartpole_mujoco", "--controller", controller, "--set",
            'plant.model="pole2_slide.xml"', "--duration", "1"] + OUT, files=slide)
    add("issue51 pole made a slide, crosscheck", ["crosscheck", "double_cartpole_mujoco", "--set",
                                                  'plant.model="pole2_slide.xml"'], files=slide)
    add("issue51 pole made a slide, inspect", ["inspect", "pole2_slide.xml"], files=slide)


IDENTIFY_JIT = ["identify", "R.csv", "--model", "M.xml", "--params", "m", "--jit",
                "--segment", "0.5"]


def _json(path: Path) -> dict:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        return {"unreadable": f"{path.name}: {exc}"}


def check_left(d: Path, check: str, out: str, err: str) -> str:
    """What is wrong with what the case's command left in ``d`` ('' when nothing)."""
    kind, _, arg = check.partition(":")
    if kind == "metrics":
        m = _json(d / "K.json")
        if m.get("status") != arg:
            return f"K.json status {m.get('status')!r}, not {arg!r} ({m.get('unreadable', '')})"
        rec = d / "K.rrd"
        if not rec.exists() or rec.read_bytes()[:4] != b"RRF2" or rec.stat().st_size < 1000:
            return "no recording K.rrd"
        if arg == "joint_limit" and not (m.get("max_abs_u") or 99) <= 10.0:
            return f"max_abs_u {m.get('max_abs_u')} > 10 V"
        return ""
    if kind == "rows":
        try:
            import pandas as pd

            rows = pd.read_parquet(d / "new.parquet")
        except Exception as exc:  # noqa: BLE001 - any reason the table is not there
            return f"no table: {type(exc).__name__}"
        if len(rows) != 2 or not rows["run_key"].is_unique or set(rows["status"]) != {arg}:
            return f"rows {list(rows['status'])}, not 2 x {arg!r}"
        return ""
    if kind == "compared":
        return "" if "| lqr" in out or "lqr" in out else "no comparison printed"
    if kind == "inconclusive":
        m = _json(d / "K.json")
        if m.get("inconclusive") is not True or m.get("open_loop_ok") is not False:
            return f"verdict {str(m.get('verdict'))[:80]!r}"
        return "" if "nothing compared" in (m.get("verdict") or "") else "not 'nothing compared'"
    if kind == "contacts":
        m = _json(d / "K.json")
        found = m.get("contacts_at_q0")
        return "" if found and found != "none" and "rail1/cart" in found else \
            f"contacts_at_q0 {found!r}"
    if kind == "said":
        return "" if arg in err else f"stderr does not say {arg!r}"
    if kind == "notsaid":
        return f"stderr names {arg!r}" if arg in err + out else ""
    if kind == "empty":
        left = sorted(p.name for p in (d / arg).iterdir()) if (d / arg).is_dir() else ["(gone)"]
        return f"{arg}/ holds {left[:5]}" if left else ""
    if kind == "png":
        return "" if (d / arg).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" else f"{arg} is no PNG"
    raise ValueError(f"unknown check {check}")


# -- running them ------------------------------------------------------------------------
def prepare(d: Path, case: Case) -> None:
    make_user_files(d)
    for name, content in case.files.items():
        p = d / name
        if isinstance(content, bytes):
            p.write_bytes(content)
        else:
            p.write_text(content)
    if case.setup == "big_scenario":
        with open(d / "Big.toml", "wb") as f:
            f.truncate(8 * 2**30)
    elif case.setup == "big_model":
        with open(d / "Big.xml", "wb") as f:
            f.truncate(8 * 2**30)
    elif case.setup == "dir_scenario":
        (d / "Dir.toml").mkdir()
    elif case.setup == "fifo_scenario":
        os.mkfifo(d / "F.toml")
    elif case.setup == "links":
        os.symlink("S.toml", d / "link.rrd")
        os.link(d / "S.toml", d / "hard.json")
        (d / "dir.rrd").mkdir()
        (d / "RO.rrd").write_bytes(b"RRF2 old")
        os.chmod(d / "RO.rrd", 0o444)
        (d / "rodir").mkdir()
        os.chmod(d / "rodir", 0o555)
        os.mkfifo(d / "fifo.rrd")
    elif case.setup == "journal_symlink":
        os.symlink("notes.txt", d / "J.parquet.journal")
    elif case.setup == "journal_corrupt":
        (d / "C.parquet.journal").write_bytes(b'{"run_key": ["not", "a", "key"]}\n' +
                                              os.urandom(2000))
    elif case.setup == "journal_other":
        (d / "O.parquet.journal").write_text('{"tspend_journal": "Mine.parquet"}\n')
    elif case.setup == "journal_hardlink":
        os.link(d / "notes.txt", d / "H.parquet.journal")
    if case.setup.startswith("cache:"):
        _damage_cache(d, d.parent, case.setup.partition(":")[2])
    elif case.setup == "full_fs":
        (d / "full").mkdir()
        subprocess.run(["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(d / "full")],
                       check=True)
        with open(d / "full" / "fill", "wb") as f:   # until the file system is full
            try:
                while True:
                    f.write(b"\0" * 65536)
                    f.flush()
            except OSError:
                pass
        (d / "full" / "cache").mkdir(exist_ok=True)
    elif case.setup == "identify_jit_garbage":
        env = dict(os.environ, TSPEND_CACHE_DIR=str(d / "cache"))
        subprocess.run([sys.executable, "-m", "tspend.cli", *IDENTIFY_JIT], cwd=d, env=env,
                       capture_output=True, timeout=900)
        for so in (d / "cache" / "articulated" / "identify").glob("*.so"):
            so.write_bytes(b"\x7fELF" + os.urandom(4000))
    elif case.setup == "tmp":
        (d / "tmp").mkdir()
    if case.setup == "locked_partial":
        # another run holds .K.partial.rrd: a helper process keeps it locked
        (d / ".K.partial.rrd").write_bytes(b"")


@dataclass
class Outcome:
    case: Case
    status: int | None
    err: str
    out: str
    lost: list[str]
    stray: list[str]
    left: list[str] = field(default_factory=list)   # processes still running in the directory
    twin_status: int | None = None
    skipped: str = ""
    problem: str = ""          # what the case's check found wrong

    @property
    def traceback(self) -> bool:
        return "Traceback (most recent call last)" in self.err + self.out

    @property
    def internal(self) -> bool:
        """An internal error (exit 70, or a traceback) where the case expected another."""
        return (self.status == 70 or self.twin_status == 70 or self.traceback) \
            and self.case.expect != 70

    @property
    def hang(self) -> bool:
        return self.status is None

    @property
    def one_line(self) -> bool:
        return len([l for l in self.err.splitlines() if l.strip()]) == 1

    @property
    def one_line_besides_warnings(self) -> bool:
        """A run that was accepted may also warn (e.g. of the model's departures)."""
        return len([l for l in self.err.splitlines()
                    if l.strip() and not l.startswith("tspend: warning:")]) == 1

    @property
    def clean(self) -> bool:
        if self.skipped:
            return True
        if self.hang or self.traceback or self.lost or self.stray or self.left:
            return False
        if self.case.check:
            return self.status == self.case.expect and not self.problem
        if self.case.expect == 0:
            # progress lines of a sweep go to stderr too: only an error is wrong
            return self.status == 0 and "error" not in self.err
        if self.case.expect == 2:
            return self.status == 2 and self.one_line
        if self.case.expect == -2:  # two commands at once: each ends with 0 or 2
            return self.status in (0, 2) and self.twin_status in (0, 2)
        if self.case.expect == -9:  # killed outright: nothing lost, nothing left running
            return self.status == -9
        return self.status == self.case.expect and self.one_line_besides_warnings


def _in_directory(d: Path) -> list[int]:
    """Processes whose working directory is ``d`` (what a command left running there)."""
    found = []
    target = str(d)
    for entry in os.listdir("/proc"):
        if not entry.isdigit() or int(entry) == os.getpid():
            continue
        try:
            if os.readlink(f"/proc/{entry}/cwd") != target:
                continue
            with open(f"/proc/{entry}/stat") as f:
                if f.read().rsplit(")", 1)[1].split()[0] == "Z":
                    continue
        except OSError:
            continue
        found.append(int(entry))
    return found


def _left_running(d: Path, grace_s: float = 5.0) -> list[str]:
    """Processes still in ``d`` ``grace_s`` after the command ended (then killed)."""
    deadline = time.monotonic() + grace_s
    while True:
        pids = _in_directory(d)
        if not pids or time.monotonic() > deadline:
            break
        time.sleep(0.25)
    names = []
    for pid in pids:
        try:
            with open(f"/proc/{pid}/cmdline", "rb") as f:
                command = f.read().replace(b"\0", b" ").decode(errors="replace")
            names.append(f"{pid}: {command[:80]}")
            os.kill(pid, signal.SIGKILL)  # a process this benchmark's case started
        except OSError:
            pass
    return names


def _verify_twin(d: Path, statuses: list[int | None], argvs: list[list[str]]) -> list[str]:
    """Rows of a sweep that exited 0 missing from the table: lost."""
    lost = []
    try:
        import pandas as pd

        from tspend.sweep import read_table

        table = read_table(d / "two.parquet")
        have = set(table["seed"]) if len(table) else set()
    except Exception as exc:  # noqa: BLE001
        return [f"two.parquet unreadable ({exc})"] if 0 in statuses else []
    for status, argv in zip(statuses, argvs):
        if status == 0:
            a, b = map(int, argv[argv.index("--seeds") + 1].split(":"))
            missing = set(range(a, b)) - have
            if missing:
                lost.append(f"two.parquet: seeds {sorted(missing)} of a sweep that exited 0")
    return lost


def run_case(case: Case, base: Path, index: int) -> Outcome:
    if case.needs and importlib.util.find_spec(case.needs.rpartition(".")[0] or case.needs) \
            is None:
        return Outcome(case, None, "", "", [], [], skipped=f"{case.needs} is not there")
    if case.needs and importlib.util.find_spec(case.needs) is None and \
            not _has_attribute(case.needs):
        return Outcome(case, None, "", "", [], [], skipped=f"{case.needs} is not there")
    d = base / f"case{index:03d}"
    d.mkdir()
    prepare(d, case)
    before = snapshot(d)
    locker = None
    lock_target = {"locked_partial": ".K.partial.rrd", "table_locked": "L.parquet.lock"}.get(
        case.setup)
    if lock_target:
        locker = subprocess.Popen([sys.executable, "-c", "import fcntl,os,sys,time;"
                                   "f=open(sys.argv[1],'ab');fcntl.flock(f,fcntl.LOCK_EX);"
                                   "f.write(str(os.getpid()).encode());f.flush();"
                                   "print('ok',flush=True);time.sleep(300)",
                                   str(d / lock_target)], stdout=subprocess.PIPE, text=True)
        locker.stdout.readline()
        before = snapshot(d)
    env = dict(os.environ)
    env.update({k: v.replace("{d}", str(d)) for k, v in case.env.items()})
    if case.api:
        cmd = [sys.executable, "-c", API_PRELUDE, case.api]
    else:
        cmd = [sys.executable, "-m", "tspend.cli", *case.argv]
    # a killed command's orphans may hold its pipes open: its output goes to files instead
    killed = case.send is not None and case.send[0] == signal.SIGKILL
    sink = [open(base / f"case{index:03d}.{n}", "w+b") for n in ("out", "err")] if killed \
        else [subprocess.PIPE, subprocess.PIPE]
    proc = subprocess.Popen(cmd, cwd=d, stdout=sink[0], stderr=sink[1], env=env,
                            start_new_session=True)
    twin = None
    if case.twin is not None:
        twin = subprocess.Popen([sys.executable, "-m", "tspend.cli", *case.twin], cwd=d,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env,
                                start_new_session=True)
    out = err = ""
    twin_status = None
    try:
        if case.head:
            first = proc.stdout.readline()
            proc.stdout.close()
            err = proc.stderr.read().decode(errors="replace")
            proc.wait(timeout=TIMEOUT_S)
            out = first.decode(errors="replace")
        else:
            if case.send is not None:
                time.sleep(case.send[1])
                proc.send_signal(case.send[0])
            if killed:
                proc.wait(timeout=TIMEOUT_S)
                sink[0].seek(0)
                sink[1].seek(0)
                out = sink[0].read().decode(errors="replace")
                err = sink[1].read().decode(errors="replace")
                for f in sink:
                    f.close()
            else:
                o, e = proc.communicate(timeout=TIMEOUT_S)
                out, err = o.decode(errors="replace"), e.decode(errors="replace")
        status = proc.returncode
        if twin is not None:
            o, e = twin.communicate(timeout=TIMEOUT_S)
            twin_status = twin.returncode
            err += e.decode(errors="replace")
    except subprocess.TimeoutExpired:
        for p in (proc, twin):
            if p is not None:
                try:
                    os.killpg(p.pid, signal.SIGKILL)
                except OSError:
                    pass
                p.communicate()
        status = None
    finally:
        if locker is not None:
            locker.kill()
            locker.wait()
    if status == 77 and case.api:
        _cleanup(d)
        return Outcome(case, None, err, out, [], [], skipped=err.strip()[:120])
    left = _left_running(d)
    after = snapshot(d)
    allowed = case.may_write
    lost = [p for p, h in before.items() if after.get(p) != h and not p.startswith(allowed)]
    if case.twin is not None:
        lost += _verify_twin(d, [status, twin_status], [case.argv, case.twin])
    stray = [p for p in after if p not in before and not p.startswith(allowed)
             and not (p.startswith("runs/") and "partial" not in p and ".." not in p)]
    if case.expect == -9:  # a killed sweep's journal and lock file are its table's
        stray = [p for p in stray if not p.startswith("k.parquet")]
    stray += [str(p.relative_to(d)) for p in d.rglob("MUJOCO_LOG.TXT")]
    problem = check_left(d, case.check, out, err) if case.check and status is not None else ""
    _cleanup(d)
    return Outcome(case, status, err, out, lost, sorted(set(stray)), left, twin_status,
                   problem=problem)


def _has_attribute(dotted: str) -> bool:
    """``tspend.linearize``: whether the module has the attribute (without failing)."""
    module, _, name = dotted.rpartition(".")
    try:
        return hasattr(importlib.import_module(module), name)
    except Exception:  # noqa: BLE001
        return False


def _cleanup(d: Path) -> None:
    if os.path.ismount(d / "full"):   # the full_fs case's tmpfs
        subprocess.run(["umount", str(d / "full")], check=False)
    for p in d.rglob("*"):
        try:
            if p.is_dir() and not p.is_symlink():
                os.chmod(p, 0o755)
        except OSError:
            pass
    shutil.rmtree(d, ignore_errors=True)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("-k", default="", help="only cases whose name contains this (or one of "
                                           "several, comma-separated)")
    ap.add_argument("-j", type=int, default=2, help="cases at a time (default 2)")
    ap.add_argument("--json", metavar="PATH", help="also write the counts as JSON")
    args = ap.parse_args()
    wanted = args.k.split(",")
    selected = [c for c in cases() if any(k in c.name for k in wanted)]
    if not args.k:
        # short mode: every 25th case (a smoke run of the harness, not the census)
        selected = selected[::sized(1, 25)]
    base = Path(tempfile.mkdtemp(prefix="tspend-hostile-"))
    started = time.perf_counter()
    with ThreadPoolExecutor(args.j) as pool:
        outcomes = list(pool.map(lambda ic: run_case(ic[1], base, ic[0]), enumerate(selected)))
    shutil.rmtree(base, ignore_errors=True)
    skipped = [o for o in outcomes if o.skipped]
    ran = [o for o in outcomes if not o.skipped]
    for o in ran:
        if not o.clean:
            first = (o.err.strip().splitlines() or [""])[0][:160]
            print(f"NOT CLEAN  {o.case.name[:50]:<50} status={o.status} expect={o.case.expect} "
                  f"lines={len(o.err.splitlines())} lost={o.lost} stray={o.stray} "
                  f"left={o.left} :: {o.problem + ' :: ' if o.problem else ''}{first}")
    notes = sorted({o.skipped for o in skipped})
    for note in notes:
        n = sum(o.skipped == note for o in skipped)
        print(f"SKIPPED    {n} case(s): {note}")
    bad_input = [o for o in ran if o.case.expect == 2]
    counts = {
        "cases": len(ran),
        "skipped": len(skipped),
        "bad inputs": len(bad_input),
        "clean exit 2": sum(o.clean for o in bad_input),
        "other cases as documented": sum(o.clean for o in ran if o.case.expect != 2),
        "other cases": len(ran) - len(bad_input),
        "internal errors (exit 70 or traceback)": sum(o.internal for o in ran),
        "data lost": sum(bool(o.lost) for o in ran),
        "processes left": sum(bool(o.left) for o in ran),
        "stray files": sum(bool(o.stray) for o in ran),
        "hangs": sum(o.hang for o in ran),
        "wall time s": round(time.perf_counter() - started),
    }
    print()
    print(f"cases                         {counts['cases']} (+{counts['skipped']} skipped)")
    print(f"clean exit 2 with one line    {counts['clean exit 2']} of {counts['bad inputs']} "
          f"bad inputs")
    print(f"other cases as documented     {counts['other cases as documented']} of "
          f"{counts['other cases']} (runs, signals, kills, two sweeps on one table)")
    print(f"internal errors (70)          {counts['internal errors (exit 70 or traceback)']}")
    print(f"data lost                     {counts['data lost']}")
    print(f"processes left                {counts['processes left']}")
    print(f"stray files                   {counts['stray files']}")
    print(f"hangs (> {TIMEOUT_S:.0f} s)              {counts['hangs']}")
    print(f"wall time                     {counts['wall time s']} s")
    if args.json:
        Path(args.json).write_text(json.dumps(counts, indent=1) + "\n")
    worst = any(o.internal or o.hang or o.lost or o.left for o in ran)
    return 1 if worst else 0


if __name__ == "__main__":
    sys.exit(main())
