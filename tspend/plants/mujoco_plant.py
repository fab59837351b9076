"""MuJoCo plants: :class:`MujocoPlant` steps any compiled hinge/slide MJCF (every MuJoCo
machine's plant, the cart-pole's included, is the articulated domain's on it:
:class:`~tspend.plants.articulated.domain.ArticulatedMujoco`), and what compiled loops
need of MuJoCo (:class:`MujocoLink`, :func:`mj_step_pointer`).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Final, NamedTuple

import mujoco
import numpy as np

from tspend.runtime.errors import DivergenceError, ScenarioError
from tspend.plants.base import Plant

# MuJoCo's "huge value" threshold (mjMAXVAL): beyond it, ctrl is ignored with a warning.
_MJ_MAXVAL: Final[float] = 1e10


class MujocoLink(NamedTuple):
    """One model and its data as compiled code steps them (:mod:`tspend.loop.fastloop`): the
    addresses of mjModel and mjData for ``mj_step``, MjData's arrays in place, the degree of
    freedom ``d`` pushes (``omega``, times ``d_to_tau``), the motor and the step's constants."""

    model_address: int
    data_address: int
    qpos: np.ndarray
    qvel: np.ndarray
    ctrl: np.ndarray
    qfrc: np.ndarray
    warning_number: np.ndarray
    bad_qpos: int
    bad_qvel: int
    bad_qacc: int
    omega: int
    actuator: int
    d_to_tau: float
    nstep: int
    max_input: float


def mj_step_pointer() -> Any:
    """MuJoCo's C ``mj_step(const mjModel*, mjData*)`` as a ctypes function, which compiled
    code calls without Python (the library the bindings themselves loaded)."""
    global _MJ_STEP
    if _MJ_STEP is None:
        import ctypes
        import glob
        import os

        here = os.path.dirname(mujoco.__file__)
        libs = sorted(glob.glob(os.path.join(here, "libmujoco.so*"))
                      + glob.glob(os.path.join(here, "libmujoco*.dylib"))
                      + glob.glob(os.path.join(here, "mujoco.dll")))
        if not libs:
            return None
        fn = ctypes.CDLL(libs[0]).mj_step
        fn.restype, fn.argtypes = None, [ctypes.c_void_p, ctypes.c_void_p]
        _MJ_STEP = fn
    return _MJ_STEP


_MJ_STEP: Any = None


def whole_substeps(dt: float, timestep: float, where: Any) -> int:
    """The number of physics steps of ``timestep`` in a control period ``dt`` (every MuJoCo
    plant's); ScenarioError naming ``where`` when ``dt`` is not a whole multiple of it."""
    k = round(dt / timestep)
    if k < 1 or abs(k * timestep - dt) > 1e-9 * max(dt, timestep):
        raise ScenarioError(f"{where}: control period dt={dt!r} is not a whole "
                            f"multiple of the model timestep {timestep!r}: set plant.timestep "
                            f"(e.g. plant.timestep = {dt:g}) or run.dt to a multiple of it")
    return int(k)


def refuse_huge_input(name: str, u: float, d: float, t: float) -> None:
    """DivergenceError for a non-finite or huge ``u`` or ``d``: MuJoCo would otherwise zero
    a bad ctrl silently."""
    if not (abs(u) < _MJ_MAXVAL and abs(d) < _MJ_MAXVAL):  # NaN fails both comparisons
        raise DivergenceError(f"{name}: non-finite or huge input u={u}, d={d} at t={t:.6g}")


def instability_error(name: str, warnings: Any, t0: float) -> DivergenceError | None:
    """The error of a step from ``t0`` in which MuJoCo found NaN, Inf or huge values (its
    ``warnings`` BADQPOS, BADQVEL, BADQACC counted) and reset the simulation; None if not."""
    if warnings[0].number or warnings[1].number or warnings[2].number:
        return DivergenceError(f"{name}: MuJoCo found NaN, Inf or huge values in qpos, qvel "
                               f"or qacc and reset the simulation (step from t={t0:.6g})")
    return None


def active_constraint(m: mujoco.MjModel, d: mujoco.MjData) -> str:
    """What constraint MuJoCo applies in the state of ``d`` now or at its next step ("" =
    none: the equations hold): a limited joint at or within its margin of its range, or a
    contact (the first one found; ``d.ncon`` as the last ``mj_forward`` or step of ``d``
    left it).  Dry friction is a departure named before the run; what else makes
    constraints (tendons, equalities) is refused or named before it too.  Any data of the
    model, not only a plant's own: the cross-check asks it of each random state."""
    for j in range(m.njnt):
        if m.jnt_limited[j]:
            q = float(d.qpos[m.jnt_qposadr[j]])
            lo, hi = (float(v) for v in m.jnt_range[j])
            margin = float(m.jnt_margin[j])
            if q <= lo + margin or q >= hi - margin:
                return (f"joint '{m.joint(j).name}' reached its range [{lo:g}, {hi:g}] "
                        f"(at {q:.6g})")
    if d.ncon > 0:
        c = d.contact[0]
        return (f"contact between geoms '{m.geom(int(c.geom[0])).name}' and "
                f"'{m.geom(int(c.geom[1])).name}'")
    return ""


class MujocoPlant(Plant):
    """A compiled hinge/slide MJCF stepped by MuJoCo, behind the Plant protocol: what every
    MuJoCo plant shares (the cart-pole's, the articulated domain's, the Furuta's).

    A subclass compiles its model and calls :meth:`_attach` with the actuator ``u`` drives
    and the degree of freedom ``d`` pushes (a generalised force ``d_to_tau d``); it says how
    :meth:`reset` places the joints (:meth:`_place`) and names the state ``[qpos; qvel]``
    (:class:`~tspend.plants.articulated.domain.ArticulatedMujoco`: from its machine).
    """

    order: int = 2

    def _attach(self, model: mujoco.MjModel, model_path: str | Path, actuator: int,
                d_dof: int, d_to_tau: float = 1.0) -> None:
        self.model, self.model_path = model, Path(model_path)
        self.data: mujoco.MjData = mujoco.MjData(model)
        self._act, self._d_dof, self._d_to_tau = int(actuator), int(d_dof), d_to_tau
        self._ts = float(model.opt.timestep)
        # dt -> substep count, so the common case (same dt every call) skips the check
        self._last_dt, self._last_k = math.nan, 0
        # numpy views into MjData, taken once: fetching them through the binding costs
        # more per step than the physics of a small model
        d = self.data
        self._qpos, self._qvel = d.qpos, d.qvel
        self._ctrl, self._qfrc = d.ctrl, d.qfrc_applied
        # MuJoCo silently resets the simulation on NaN/huge qpos, qvel or qacc and only
        # counts a warning: watch those counters so a blow-up cannot pass as [0, 0]
        w = mujoco.mjtWarning
        self._warnings = [d.warning[int(k)] for k in
                          (w.mjWARN_BADQPOS, w.mjWARN_BADQVEL, w.mjWARN_BADQACC)]

    def mj_model(self) -> mujoco.MjModel:
        return self.model

    def full_state(self) -> np.ndarray:
        return np.concatenate((self._qpos, self._qvel))

    @property
    def timestep(self) -> float:
        """The physics timestep; ``step``'s dt must be a whole multiple of it."""
        return self._ts

    @property
    def t(self) -> float:
        """Simulated time since the last reset."""
        return float(self.data.time)

    def constraint_active(self) -> str:
        """What constraint MuJoCo applies now or at its next step ("" = none: the equations
        hold): :func:`active_constraint` of this plant's own data."""
        return active_constraint(self.model, self.data)

    def _place(self, x0: np.ndarray) -> None:
        """Write the initial state of ``x0`` into ``self.data`` (after ``mj_resetData``)."""
        raise NotImplementedError

    def reset(self, x0: np.ndarray) -> None:
        """The model's reset state with :meth:`_place`'s ``x0``, no input, clock at 0."""
        mujoco.mj_resetData(self.model, self.data)
        self._place(np.asarray(x0, dtype=float))
        mujoco.mj_forward(self.model, self.data)

    def compiled_mujoco(self, dt: float) -> MujocoLink | None:
        """This plant for a compiled closed loop (:mod:`tspend.loop.fastloop` calls MuJoCo's
        C ``mj_step`` on its model and data) at sample time ``dt``; None when MuJoCo's
        library cannot be found."""
        if mj_step_pointer() is None:
            return None
        w = mujoco.mjtWarning
        return MujocoLink(self.model._address, self.data._address, self._qpos, self._qvel,
                          self._ctrl, self._qfrc, self.data.warning.number,
                          int(w.mjWARN_BADQPOS), int(w.mjWARN_BADQVEL), int(w.mjWARN_BADQACC),
                          self._d_dof, self._act, self._d_to_tau, self._substeps(dt), _MJ_MAXVAL)

    def instability(self, t0: float) -> DivergenceError | None:
        """The error :meth:`step` raises when MuJoCo found NaN, Inf or huge values (and
        reset the simulation) in a step from time ``t0``; None when it did not."""
        return instability_error(self.name, self._warnings, t0)

    def step(self, u: float, d: float, dt: float) -> None:
        """Advance by ``dt`` (a whole number of physics steps) with u and d held.

        Raises ScenarioError if dt is not a multiple of the timestep, DivergenceError if
        u or d is not finite or MuJoCo had to reset an unstable simulation.
        """
        if dt != self._last_dt:
            self._last_k = self._substeps(dt)
            self._last_dt = dt
        refuse_huge_input(self.name, u, d, self.data.time)
        t0 = self.data.time
        self._ctrl[self._act] = u
        self._qfrc[self._d_dof] = self._d_to_tau * d
        mujoco.mj_step(self.model, self.data, self._last_k)
        unstable = self.instability(t0)
        if unstable is not None:
            raise unstable

    def check_sample_time(self, dt: float) -> None:
        """Raise ScenarioError now, before a run, if dt is not a multiple of the timestep."""
        self._substeps(dt)

    def _substeps(self, dt: float) -> int:
        return whole_substeps(dt, self._ts, self.model_path)


def guess_names(model_path: str | Path, slide: str | None, hinge: str | None,
                actuator: str | None) -> tuple[str, str, str]:
    """Joint and actuator names: the given ones, else the model's only slide joint, only
    hinge joint and only actuator on that slide (ScenarioError when ambiguous)."""
    from tspend.plants.articulated.machine import open_spec

    where, spec = str(model_path), open_spec(model_path)

    def only(found: list[str], what: str, flag: str) -> str:
        if len(found) != 1:
            raise ScenarioError(f"{where}: {len(found)} {what} ({', '.join(found) or 'none'}); "
                                f"name one with {flag}")
        return found[0]

    joints = list(spec.joints)
    slide = slide or only([j.name for j in joints if j.type == mujoco.mjtJoint.mjJNT_SLIDE],
                          "slide joints", "--slide")
    hinge = hinge or only([j.name for j in joints if j.type == mujoco.mjtJoint.mjJNT_HINGE],
                          "hinge joints", "--hinge")
    actuator = actuator or only([a.name for a in spec.actuators if a.target == slide],
                                f"actuators on '{slide}'", "--actuator")
    return slide, hinge, actuator
