"""MuJoCo plants: :class:`MujocoPlant` steps any compiled hinge/slide MJCF (the
articulated domain's and the Furuta's plants are it with their machine's roles), and
:class:`MujocoCartPole` is the cart-pole on it (``models/cartpole.xml`` reproduces the
paper's Example 3, docs/paper-notes.md section 7): the state ``x = [theta, theta']`` of
its hinge, ``u`` the actuator's control, the disturbance ``d_d`` the hinge torque
:attr:`~tspend.plants.mjcf.CartPoleParams.disturbance_torque` ``d_d`` (in generalised
coordinates, ``qfrc_applied``, so independent of the hinge axis' convention), and its
``[plant]`` numbers written into the model through ``MjSpec`` and read back from the
compiled one (:attr:`MujocoCartPole.params`), so the ODE twin is the same machine.
"""

from __future__ import annotations

import math
from pathlib import Path
from dataclasses import replace
from functools import cached_property
from typing import Any, Final, NamedTuple

import mujoco
import numpy as np

from tspend.errors import DivergenceError, ScenarioError
from tspend.plants import mjcf
from tspend.plants.base import InputInfo, JointInfo, Plant, TaskDefaults, velocity_name
from tspend.plants.mjcf import OVERRIDABLE, CartPoleParams

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


def _names(elements: Any) -> str:
    return ", ".join(e.name or "<unnamed>" for e in elements) or "none"


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
    :meth:`reset` places the joints (:meth:`_place`).  The state is ``[qpos; qvel]``, each
    joint's position named after it and its velocity ``<joint>_dot``.
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
        names = [model.joint(j).name or f"joint{j}" for j in range(model.njnt)]
        slide = [int(model.jnt_type[j]) == int(mujoco.mjtJoint.mjJNT_SLIDE)
                 for j in range(model.njnt)]
        units = tuple("m" if s else "rad" for s in slide)
        self._state_names = tuple(names) + tuple(velocity_name(n) for n in names)
        self._state_units = units + tuple(f"{u}/s" for u in units)
        self._joints = tuple(
            JointInfo(n, "slide" if s else "hinge", u,
                      (float(model.jnt_range[j, 0]), float(model.jnt_range[j, 1]))
                      if model.jnt_limited[j] else None)
            for j, (n, s, u) in enumerate(zip(names, slide, units)))

    def mj_model(self) -> mujoco.MjModel:
        return self.model

    @property
    def state_names(self) -> tuple[str, ...]:
        """Every joint's position (qpos), then every velocity (qvel), named after the joints."""
        return self._state_names

    @property
    def state_units(self) -> tuple[str, ...]:
        return self._state_units

    @property
    def joints(self) -> tuple[JointInfo, ...]:
        """Every joint of the compiled model, its range when ``limited``."""
        return self._joints

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


class MujocoCartPole(MujocoPlant):
    """Example 3's cart-pole as a MuJoCo model, behind the Plant protocol.

    Parameters
    ----------
    model_path:
        MJCF file, e.g. ``models/cartpole.xml``.
    slide_joint, hinge_joint, actuator:
        names of the cart's slide joint, the pole's hinge and the motor on the slider.
    overrides:
        what to write into the model before compiling (verified on the compiled model):
        a dict of some of M, m, l, J, g (the rest stay the model's own), or a
        :class:`CartPoleParams` for all of them.  The pole's COM moves to ``l`` from the
        pivot along the pole, its inertia becomes J (the uniform rod's 4/3 m l^2 unless
        given) and the pole's visual geoms stretch with it.  None: the model as it is.
    integrator:
        ``"RK4"`` (the model's default, matches the ODE), ``"Euler"``, ``"implicit"`` or
        ``"implicitfast"``; only for the cross-check's contrast figures.
    timestep:
        overrides the model's physics timestep.
    gear:
        if given, the actuator's gain (cart force per unit of u) written into the model
        and read back from the compiled one.
    ctrl_unbounded:
        True leaves u unbounded (the actuator's ``ctrlrange`` off): the paper's machine.
    task_defaults:
        the domain's default task, its states named by the roles ``slider``/``hinge``
        (the cart-pole domain's: fall at pi/2); default: the hinge's view, no fall.

    Raises
    ------
    ScenarioError
        missing or unparsable model file, missing or mistyped joint or actuator, an
        actuator that does not drive the slide joint, or an unknown integrator.
    """

    name: str = "cartpole_mujoco"
    domain: str = "cartpole"

    def __init__(self, model_path: str | Path, slide_joint: str = "slider",
                 hinge_joint: str = "hinge", actuator: str = "force",
                 overrides: CartPoleParams | dict[str, float] | None = None,
                 integrator: str | None = None, timestep: float | None = None,
                 cart_damping: float | None = None, hinge_damping: float | None = None,
                 cart_friction: float | None = None, hinge_friction: float | None = None,
                 task_defaults: TaskDefaults | None = None, gear: float | None = None,
                 ctrl_unbounded: bool = False) -> None:
        self._task_defaults = task_defaults or TaskDefaults(view=("hinge", "hinge_dot"))
        where = str(model_path)
        from tspend.plants.articulated.machine import open_spec

        spec = open_spec(model_path, timestep, integrator or "")

        slide = self._spec_joint(spec, slide_joint, mujoco.mjtJoint.mjJNT_SLIDE, "slide", where)
        hinge = self._spec_joint(spec, hinge_joint, mujoco.mjtJoint.mjJNT_HINGE, "hinge", where)
        act = spec.actuator(actuator)
        if act is None:
            raise ScenarioError(f"{where}: no actuator named {actuator!r} "
                                f"(actuators in the model: {_names(spec.actuators)})")
        if act.trntype != mujoco.mjtTrn.mjTRN_JOINT or act.target != slide_joint:
            raise ScenarioError(f"{where}: actuator {actuator!r} drives {act.target!r}, "
                                f"not the slide joint {slide_joint!r}")

        for joint, damping, friction in ((slide, cart_damping, cart_friction),
                                         (hinge, hinge_damping, hinge_friction)):
            if damping is not None:  # MuJoCo 4 keeps [linear, 0, 0] damping coefficients
                joint.damping = [damping, 0.0, 0.0]
            if friction is not None:
                joint.frictionloss = friction
        if gear is not None:
            mjcf.apply_gear(act, gear, where)
        if ctrl_unbounded:  # the paper's machine: no bound on u
            act.ctrllimited = mujoco.mjtLimited.mjLIMITED_FALSE
        keys, target = self._override_keys(spec, overrides, slide_joint, hinge_joint,
                                           actuator, where)
        if keys:
            pivot = np.asarray(hinge.pos, dtype=float)
            axis = mjcf._pole_direction(hinge.parent, pivot)
            old_l = float(np.linalg.norm(np.asarray(hinge.parent.ipos, dtype=float) - pivot))
            mjcf.apply_overrides(spec, slide.parent, hinge, target, where, keys)
            if "l" in keys and old_l > 0.0 and target.l != old_l:
                self._stretch_pole_geoms(hinge.parent, pivot, axis, target.l / old_l)

        try:
            self.model: mujoco.MjModel = spec.compile()
        except ValueError as exc:
            raise ScenarioError(f"{where}: cannot compile MJCF: {exc}") from exc
        if not (self.model.opt.timestep > 0.0 and math.isfinite(self.model.opt.timestep)):
            raise ScenarioError(f"{where}: option timestep must be a positive number, got "
                                f"{self.model.opt.timestep!r}")
        self.slide_joint, self.hinge_joint, self.actuator = slide_joint, hinge_joint, actuator

        m = self.model
        self._slide_id = m.joint(slide_joint).id
        self._hinge_id = m.joint(hinge_joint).id
        self._cart_body = int(m.jnt_bodyid[self._slide_id])
        self._pole_body = int(m.jnt_bodyid[self._hinge_id])
        self._q_cart = int(m.jnt_qposadr[self._slide_id])
        self._v_cart = int(m.jnt_dofadr[self._slide_id])
        self._q_th = int(m.jnt_qposadr[self._hinge_id])

        self.facts = mjcf.read_facts(m, slide_joint, hinge_joint, actuator, where)
        if keys:
            checked = keys | ({"J"} if keys & {"m", "l", "J"} else set())
            mjcf.verify_overrides(self.facts, target, m.body(self._cart_body).name,
                                  m.body(self._pole_body).name, where, frozenset(checked))
        if gear is not None:
            mjcf.verify_gear(self.facts, gear, actuator, where)
        #: what the scenario wrote into the model (name -> value); empty: the model's own
        self.overridden: dict[str, float] = {k: float(getattr(target, k)) for k in sorted(keys)}
        if gear is not None:
            self.overridden["gear"] = float(gear)
        self._params = self.facts.params()
        # d_d enters theta'' like a hinge torque tau = -d_d m l / (M + m) (module docstring).
        self._attach(m, model_path, m.actuator(actuator).id, m.jnt_dofadr[self._hinge_id],
                     self._params.disturbance_torque)
        a = self._act
        lo, hi = (float(v) for v in m.actuator_ctrlrange[a]) if m.actuator_ctrllimited[a] \
            else (-math.inf, math.inf)
        # u is what the actuator takes: a force for a motor, a speed or a position for a
        # velocity or position servo
        unit = {"velocity": "m/s", "position": "m"}.get(self.facts.actuator_type, "N")
        per_unit = self.facts.gear * self.facts.gain
        if unit == "N" and per_unit != 1.0 and "gear" not in self.overridden:
            # the model's own gear or gain other than 1: u is its control, the force beside
            # it (a gear the scenario sets or draws is plant.gear: u stays the ODE's force)
            self._inputs = (InputInfo(self.actuator, "ctrl", lo, hi, "N", per_unit),)
        else:
            self._inputs = (InputInfo(self.actuator, unit, lo, hi),)
        self.reset(np.zeros(2))

    # --- construction helpers -------------------------------------------------------

    @staticmethod
    def _spec_joint(spec: mujoco.MjSpec, name: str, jtype: mujoco.mjtJoint, kind: str,
                    where: str) -> Any:
        joint = spec.joint(name)
        if joint is None:
            raise ScenarioError(f"{where}: no {kind} joint named {name!r} "
                                f"(joints in the model: {_names(spec.joints)})")
        if joint.type != jtype:
            actual = joint.type.name.removeprefix("mjJNT_").lower()
            raise ScenarioError(f"{where}: joint {name!r} is a {actual} joint, "
                                f"expected a {kind} joint")
        return joint

    @staticmethod
    def _override_keys(spec: mujoco.MjSpec, overrides: "CartPoleParams | dict[str, float] | None",
                       slide: str, hinge: str, actuator: str, where: str
                       ) -> tuple[frozenset[str], CartPoleParams]:
        """Which of M, m, l, J, g to write, and the machine they make: all of them for a
        :class:`CartPoleParams`; for a dict the keys given, the model's own values for the
        rest (J: the uniform rod's when m or l changes and J is not given)."""
        if overrides is None or (isinstance(overrides, dict) and not overrides):
            return frozenset(), CartPoleParams()
        if isinstance(overrides, CartPoleParams):
            return frozenset("MmlJg"), overrides
        unknown = sorted(set(overrides) - set(OVERRIDABLE))
        if unknown:
            raise ScenarioError(f"{where}: cannot override {', '.join(unknown)} (overridable: "
                                f"{', '.join(OVERRIDABLE)})")
        try:
            # a copy: compiling the spec itself keeps its geoms' masses over the explicit
            # inertial written later (an M override on gymnasium's model did not take)
            own = mjcf.read_facts(spec.copy().compile(), slide, hinge, actuator, where)
        except ValueError as exc:
            raise ScenarioError(f"{where}: cannot compile MJCF: {exc}") from exc
        base = CartPoleParams(M=own.cart_mass, m=own.pole_mass, l=own.pole_com, g=own.gravity,
                              J=own.pole_inertia_pivot)
        values = dict(overrides)
        if ("m" in values or "l" in values) and "J" not in values:
            values["J"] = 0.0
        return frozenset(overrides), replace(base, **values)

    @staticmethod
    def _stretch_pole_geoms(pole: Any, pivot: np.ndarray, axis: np.ndarray, scale: float) -> None:
        """Stretch the pole's visual geoms along the pole so the drawing matches l.

        Positions move along the pole (the pivot stays put); capsules, cylinders and
        boxes whose own z runs along the pole get longer.  Anything across the pole
        (the pivot pin, the tip ball) keeps its size.
        """
        def along(v: np.ndarray) -> np.ndarray:
            r = v - pivot
            return pivot + r + (scale - 1.0) * float(r @ axis) * axis

        for geom in pole.geoms:
            fromto = np.asarray(geom.fromto, dtype=float)
            if not math.isnan(fromto[0]):
                geom.fromto = np.concatenate([along(fromto[:3]), along(fromto[3:])])
                continue
            geom.pos = along(np.asarray(geom.pos, dtype=float))
            gz = np.zeros(3)
            mujoco.mju_rotVecQuat(gz, np.array([0.0, 0.0, 1.0]), np.asarray(geom.quat, dtype=float))
            if abs(float(gz @ axis)) < 1.0 - 1e-9:
                continue
            size = np.asarray(geom.size, dtype=float).copy()
            if geom.type in (mujoco.mjtGeom.mjGEOM_CAPSULE, mujoco.mjtGeom.mjGEOM_CYLINDER):
                size[1] *= scale
            elif geom.type == mujoco.mjtGeom.mjGEOM_BOX:
                size[2] *= scale
            else:
                continue
            geom.size = size

    @property
    def inputs(self) -> tuple[InputInfo, ...]:
        """The motor on the slide joint, bounded by its ctrlrange when ``ctrllimited``."""
        return self._inputs

    def parameters(self) -> dict[str, float]:
        """The machine as compiled (:attr:`params`: read back from the compiled model;
        ranges that are not set left out)."""
        return self._params.finite()

    def unmodelled(self, dt: float | None = None) -> list[str]:
        """What the ODE of this model (:attr:`params`) does not reproduce."""
        return mjcf.unmodelled(self.facts, dt)

    def default_task(self) -> TaskDefaults:
        """The domain's task (``task_defaults``, in the model's ``slider``/``hinge`` roles),
        on this model's joints."""
        return self._task_defaults.renamed({"slider": self.slide_joint, "hinge": self.hinge_joint,
                                    "slider_dot": velocity_name(self.slide_joint),
                                    "hinge_dot": velocity_name(self.hinge_joint)})


    @property
    def params(self) -> CartPoleParams:
        """The ODE of the compiled model (:meth:`ModelFacts.params`): masses, COM distance,
        inertia about the pivot, joint damping and friction, gear and angle sign."""
        return self._params

    @cached_property
    def machine(self) -> Any:
        """The compiled model as the articulated domain reads it
        (:class:`~tspend.plants.articulated.machine.Machine`: its derived equations, the
        hinge its pole), built when first asked, from the model as it is then.  ScenarioError
        for a model the derivation refuses (the cart-pole steps some of those in MuJoCo)."""
        from tspend.plants.articulated.machine import Machine

        return Machine(self.model, str(self.model_path), self.actuator, (self.hinge_joint,))

    @property
    def gain_sign(self) -> int:
        """Sign of d(theta'')/du at the upright, measured on the compiled model."""
        return self.facts.gain_sign

    def departures(self, dt: float | None = None) -> list[str]:
        """How this model departs from the paper's ODE (with ``dt``: and the sample time)."""
        # a gear the scenario set (or [randomize] drew) is recorded as plant.gear
        return mjcf.departures(self.facts, dt, gear_chosen="gear" in self.overridden)

    def set_params(self, p: CartPoleParams) -> None:
        """Change M, m, l (J) of the running machine, as a payload picked up would.

        Writes the compiled model's inertials in place, exactly as an override would
        have compiled them; the state is kept.
        """
        m = self.model
        pole, cart = self._pole_body, self._cart_body
        pivot = m.jnt_pos[self._hinge_id]
        arm = m.body_ipos[pole] - pivot
        axis = arm / np.linalg.norm(arm)
        i_perp = p.pole_inertia_pivot - p.m * p.l ** 2
        if i_perp <= 0.0 or p.M <= 0.0 or p.m <= 0.0 or p.l <= 0.0:
            raise ScenarioError(f"{self.model_path}: cannot change to M={p.M:g}, m={p.m:g}, "
                                f"l={p.l:g}, J={p.pole_inertia_pivot:g}")
        m.body_mass[pole] = p.m
        m.body_ipos[pole] = pivot + p.l * axis
        quat = m.body_iquat[pole].copy()
        mujoco.mju_quatZ2Vec(quat, axis)
        m.body_iquat[pole] = quat
        m.body_inertia[pole] = (i_perp, i_perp, i_perp * mjcf.AXIAL_INERTIA_RATIO)
        carried = float(m.body_subtreemass[cart]) - float(m.body_mass[cart]) - self._params.m
        m.body_mass[cart] = p.M - carried
        m.body_subtreemass[cart] = p.M + p.m
        m.body_subtreemass[pole] = p.m
        self._params = replace(self._params, M=p.M, m=p.m, l=p.l, J=p.J)
        self._d_to_tau = self._params.disturbance_torque
        # the derived machine is read from the model: the next one asked for reads these
        self.__dict__.pop("machine", None)

    def _place(self, x0: np.ndarray) -> None:
        """Pole at ``x0 = [theta, theta']``, cart at rest where the model puts it."""
        if x0.shape != (self.order,):
            raise ValueError(f"{self.name}: initial state must have {self.order} entries, "
                             f"got {x0.shape}")
        self._qpos[self._q_th] = x0[0]
        self._qvel[self._d_dof] = x0[1]

    def extras(self) -> dict[str, float]:
        return {"cart_pos": float(self._qpos[self._q_cart]),
                "cart_vel": float(self._qvel[self._v_cart])}

    def extras_index(self) -> np.ndarray:
        """The cart's position and velocity in the full state [qpos; qvel]."""
        return np.array([self._q_cart, self.model.nq + self._v_cart], dtype=np.intp)


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
