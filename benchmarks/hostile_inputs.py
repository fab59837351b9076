"""A hostile user's sweep: ~300 bad inputs against ``tspend run``, ``crosscheck`` and ``list``.

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
  directory's ``runs/`` that the case did not ask for.

    python benchmarks/hostile_inputs.py            # all cases, 2 at a time
    python benchmarks/hostile_inputs.py -k seed    # only cases whose name contains "seed"

Prints the figures (tried, clean, tracebacks, hangs, files lost) and every case that was
not clean.  Exit status 1 if any traceback, hang or lost file was seen.
"""

from __future__ import annotations

import argparse
import hashlib
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
    # gravity comes from the scenario's g (applied with MjSpec), so a NaN in the file is moot
    add("MJCF gravity nan, g from the scenario", ["run", "Q.toml", "--duration", "0.05"] + OUT,
        expect=0, may_write=("K.rrd", "K.json"),
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
    add("--controller help", RUN + ["--controller", "help"] + OUT)
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
    return cs


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
    elif case.setup == "locked_partial":
        # another run holds K.partial.rrd: a helper process keeps it locked
        (d / "K.partial.rrd").write_bytes(b"")


@dataclass
class Outcome:
    case: Case
    status: int | None
    err: str
    out: str
    lost: list[str]
    stray: list[str]

    @property
    def traceback(self) -> bool:
        return "Traceback (most recent call last)" in self.err + self.out

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
        if self.hang or self.traceback or self.lost or self.stray:
            return False
        if self.case.expect == 0:
            return self.status == 0 and not self.err.strip()
        if self.case.expect == 2:
            return self.status == 2 and self.one_line
        return self.status == self.case.expect and self.one_line_besides_warnings


def run_case(case: Case, base: Path, index: int) -> Outcome:
    d = base / f"case{index:03d}"
    d.mkdir()
    prepare(d, case)
    before = snapshot(d)
    locker = None
    if case.setup == "locked_partial":
        locker = subprocess.Popen([sys.executable, "-c", "import fcntl,sys,time;"
                                   "f=open(sys.argv[1],'rb');fcntl.flock(f,fcntl.LOCK_EX);"
                                   "print('ok',flush=True);time.sleep(300)",
                                   str(d / "K.partial.rrd")], stdout=subprocess.PIPE, text=True)
        locker.stdout.readline()
    env = dict(os.environ)
    cmd = [sys.executable, "-m", "tspend.cli", *case.argv]
    proc = subprocess.Popen(cmd, cwd=d, stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env,
                            start_new_session=True)
    out = err = ""
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
            o, e = proc.communicate(timeout=TIMEOUT_S)
            out, err = o.decode(errors="replace"), e.decode(errors="replace")
        status = proc.returncode
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.communicate()
        status = None
    finally:
        if locker is not None:
            locker.kill()
            locker.wait()
    after = snapshot(d)
    allowed = case.may_write
    lost = [p for p, h in before.items() if after.get(p) != h and not p.startswith(allowed)]
    stray = [p for p in after if p not in before and not p.startswith(allowed)
             and not (p.startswith("runs/") and "partial" not in p and ".." not in p)]
    stray += [str(p.relative_to(d)) for p in d.rglob("MUJOCO_LOG.TXT")]
    _cleanup(d)
    return Outcome(case, status, err, out, lost, sorted(set(stray)))


def _cleanup(d: Path) -> None:
    for p in d.rglob("*"):
        try:
            if p.is_dir() and not p.is_symlink():
                os.chmod(p, 0o755)
        except OSError:
            pass
    shutil.rmtree(d, ignore_errors=True)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("-k", default="", help="only cases whose name contains this")
    ap.add_argument("-j", type=int, default=2, help="cases at a time (default 2)")
    args = ap.parse_args()
    selected = [c for c in cases() if args.k in c.name]
    base = Path(tempfile.mkdtemp(prefix="tspend-hostile-"))
    started = time.perf_counter()
    with ThreadPoolExecutor(args.j) as pool:
        outcomes = list(pool.map(lambda ic: run_case(ic[1], base, ic[0]), enumerate(selected)))
    shutil.rmtree(base, ignore_errors=True)
    bad = [o for o in outcomes if not o.clean]
    for o in bad:
        first = (o.err.strip().splitlines() or [""])[0][:160]
        print(f"NOT CLEAN  {o.case.name[:50]:<50} status={o.status} expect={o.case.expect} "
              f"lines={len(o.err.splitlines())} lost={o.lost} stray={o.stray} :: {first}")
    n_bad_input = sum(1 for o in outcomes if o.case.expect == 2)
    print()
    print(f"tried                         {len(outcomes)}")
    print(f"clean exit 2 with one line    {sum(o.clean for o in outcomes if o.case.expect == 2)}"
          f" of {n_bad_input} bad inputs")
    print(f"other cases as documented     {sum(o.clean for o in outcomes if o.case.expect != 2)}"
          f" of {len(outcomes) - n_bad_input} (sanitised names run, signals, list | head)")
    print(f"tracebacks                    {sum(o.traceback for o in outcomes)}")
    print(f"hangs (> {TIMEOUT_S:.0f} s)              {sum(o.hang for o in outcomes)}")
    print(f"files lost                    {sum(bool(o.lost) for o in outcomes)}")
    print(f"stray files                   {sum(bool(o.stray) for o in outcomes)}")
    print(f"wall time                     {time.perf_counter() - started:.0f} s")
    worst = any(o.traceback or o.hang or o.lost for o in outcomes)
    return 1 if worst else 0


if __name__ == "__main__":
    sys.exit(main())
