"""The wheel is the product: built from this checkout, installed where the checkout is not
on the path, and run from an empty folder it lists, shows and runs the shipped scenarios
(issue: tspend outside its checkout)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_the_package_list_is_every_package():
    """pyproject.toml lists the packages by hand (the shipped data are mapped packages): a
    package added to tspend/ and left out of the list would be missing from the wheel."""
    from setuptools import find_packages

    listed = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"]
    code = {p for p in listed if not p.startswith("tspend.shipped.")}
    assert code == set(find_packages(str(ROOT), include=["tspend*"]))


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """(python environment, empty working folder) with tspend from a freshly built wheel."""
    tmp = tmp_path_factory.mktemp("wheel")
    dist, site, work = tmp / "dist", tmp / "site", tmp / "work"
    work.mkdir()
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", str(dist),
                    str(ROOT)], check=True, capture_output=True, timeout=600)
    wheel = next(dist.glob("tspend-*.whl"))
    subprocess.run([sys.executable, "-m", "pip", "install", "--no-deps", "-q", "--target",
                    str(site), str(wheel)], check=True, capture_output=True, timeout=600)
    env = {k: v for k, v in os.environ.items() if k != "TSPEND_SCENARIO_PATH"}
    env["PYTHONPATH"] = str(site)
    return env, work, site


def _tspend(installed, *args, timeout=600):
    env, work, _ = installed
    return subprocess.run([sys.executable, "-m", "tspend.cli", *args], cwd=work, env=env,
                          capture_output=True, text=True, timeout=timeout)


def test_tspend_comes_from_the_wheel(installed):
    env, work, site = installed
    out = subprocess.run([sys.executable, "-c", "import tspend, tspend.shipped as s; "
                          "print(tspend.__file__); print(s.data_root())"],
                         cwd=work, env=env, capture_output=True, text=True, check=True).stdout
    package, data = out.split()
    assert Path(package).is_relative_to(site) and Path(data).is_relative_to(site)
    assert not Path(package).is_relative_to(ROOT)


def test_list_show_and_run_from_an_empty_folder(installed):
    _, work, _ = installed
    listed = _tspend(installed, "list")
    assert listed.returncode == 0, listed.stderr
    names = [line.split()[0] for line in listed.stdout.splitlines()
             if line and not line.startswith(" ") and not line.startswith("searched")]
    assert len(names) >= 35 and "pendulum_mujoco" in names and "double_cartpole_swingup" in names
    shown = _tspend(installed, "show", "pendulum_mujoco")
    assert shown.returncode == 0, shown.stderr
    (work / "p.toml").write_text(shown.stdout)
    a = _tspend(installed, "run", "p.toml", "--duration", "0.3", "--metrics", "a.json",
                "--no-record")
    b = _tspend(installed, "run", "--duration", "0.3", "--metrics", "b.json", "--out", "x.rrd")
    assert a.returncode == 0 and b.returncode == 0, a.stderr + b.stderr
    ma, mb = (json.loads((work / f).read_text()) for f in ("a.json", "b.json"))
    assert ma["steps"] == mb["steps"] == 300
    for key in ("rmse", "rmse_ss", "max_abs_u", "control_energy", "iae"):
        assert ma[key] == mb[key], key
    assert (work / "x.rrd").stat().st_size > 0
    # a planned swing-up finds its plan, and the policy kind its network, in the wheel
    plan = _tspend(installed, "run", "double_cartpole_swingup", "--duration", "0.05",
                   "--no-record")
    assert plan.returncode == 0, plan.stderr
    # the README's commands that name shipped files, from a folder that has none of them
    inspected = _tspend(installed, "inspect", "models/double_cartpole.xml")
    assert inspected.returncode == 0 and "an articulated model" in inspected.stdout, inspected.stderr
    custom = _tspend(installed, "run", "ex3_pendulum_ode", "--controller",
                     "examples/custom_controller.py:SaturatedPD", "--duration", "0.05", "--no-record")
    assert custom.returncode == 0, custom.stderr
    assert not any(p.name not in ("p.toml", "a.json", "b.json", "x.rrd") for p in work.iterdir())


def test_python_call_from_an_empty_folder(installed):
    env, work, _ = installed
    code = ("import tspend\n"
            "r = tspend.run('pendulum_mujoco', controller='lqr', duration=0.2)\n"
            "print(r.status, r.metrics['steps'])\n")
    out = subprocess.run([sys.executable, "-c", code], cwd=work, env=env, capture_output=True,
                         text=True, timeout=600)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["completed", "200"]


def test_what_the_docs_and_help_name_is_in_the_wheel(installed):
    """Issue 51, items 2, 3, 7 and 8, from an empty folder: identify finds a shipped model
    as inspect does (what is missing is then the data), the third-party models ship with
    their licences, ``tspend list --files`` says where the examples are, and the documents
    the help names are files in the install."""
    import re

    _, work, site = installed
    third = _tspend(installed, "inspect", "models/third_party/gymnasium_inverted_pendulum.xml")
    assert third.returncode == 0, third.stderr
    shipped = site / "tspend" / "shipped" / "models" / "third_party"
    assert all("License" in p.read_text() or "Apache" in p.read_text()
               for p in shipped.glob("*.xml")) and len(list(shipped.glob("*.xml"))) == 2
    fit = _tspend(installed, "identify", "e3.csv", "--model", "models/cartpole.xml",
                  "--params", "m")
    assert fit.returncode == 2 and "e3.csv" in fit.stderr and "--model" not in fit.stderr
    files = _tspend(installed, "list", "--files")
    assert files.returncode == 0 and "train_mjx_ppo.py" in files.stdout
    assert str(site / "tspend" / "shipped" / "examples") in files.stdout
    for command in ("run", "sweep"):
        text = " ".join(_tspend(installed, command, "--help").stdout.split())
        named = re.findall(r"(\S*docs/[\w/.-]+\.md)", text)
        assert named and all(Path(p).is_relative_to(site) and Path(p).is_file()
                             for p in named), named


def test_the_wheel_mode_of_check_docs_takes_the_tour_and_refuses_the_checkout():
    """tools/check_docs.py --wheel runs each document's first block with a command to run:
    the README's tour (its first two blocks install), a benchmark of the checkout skipped;
    an interpreter that imports tspend from this checkout is refused (issue 51)."""
    sys.path.insert(0, str(ROOT / "tools"))
    from check_docs_wheel import first_block, from_the_wheel

    tour = first_block(ROOT / "README.md", short=False)
    assert tour[0].text.startswith("tspend list --long") and len(tour) >= 20
    bench = [c for c in first_block(ROOT / "docs" / "safety.md", short=False)
             if "benchmarks/" in c.text]
    assert bench and all(c.skip for c in bench)
    assert "from this checkout" in from_the_wheel(sys.executable)
