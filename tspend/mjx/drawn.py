"""Many seeds' machines from one CPU build: the ``[randomize]`` draw as arrays written into
one compiled model's fields per env (:func:`tspend.mjx.machines.build_fleet`).

The CPU backend builds each seed's machine by editing the MJCF's ``MjSpec`` and compiling
it (milliseconds per seed, hours for 10^5 seeds).  Here the first seed is built so, and
every seed's draw (:func:`tspend.plants.randomize.draw_values`, equal to the CPU's draw
per seed) is written into that compiled model's fields as the spec edits leave them:

* a cart-pole's ``m``, ``l`` (:func:`tspend.plants.mjcf.apply_overrides`): the pole's
  explicit inertial, mass m, COM at l along the pole from the pivot, the transverse
  inertia J - m l^2 with J the rod's 4/3 m l^2; ``M``: the cart's mass M less what else it
  carries, its inertia scaled with it; ``gear`` (:func:`tspend.plants.mjcf.apply_gear`):
  the transmission scaled;
* a model's ``BODY.mass`` (:func:`tspend.plants.articulated.model_numbers.write_values`):
  the mass, its inertia scaled with it; ``JOINT.damping``, ``JOINT.armature``: the value;
* ``x0``: the plant's reset, an affine map measured on the built plant (checked on it).

What the compiler derives from these (subtree masses, the inverse weights at qpos0, the
mean inertia MJX's solver scales its tolerance by) comes from ``mujoco.mj_setConst`` on
one scratch copy of the model per env: microseconds, not a compile.  The geoms keep the
first seed's shapes (only the drawing shows them: the shipped models' geoms do not
collide).  tests/test_mjx.py checks the fields against each seed's CPU build.
"""

from __future__ import annotations

import copy
import dataclasses
from collections.abc import Sequence
from typing import Any

import numpy as np

from tspend.plants.randomize import draw_values

__all__ = ["DrawnMachines", "array_form", "drawn_fleet"]

#: the cart-pole keys with an array form, and a model's quantities
CARTPOLE_KEYS = ("M", "m", "l", "gear")
MODEL_QUANTITIES = ("mass", "damping", "armature")
#: the fields mj_setConst derives from the masses (read back per env)
DERIVED = ("body_subtreemass", "body_invweight0", "dof_invweight0", "dof_M0", "actuator_acc0",
           "light_poscom0", "cam_poscom0")


def array_form(scenario: Any) -> str:
    """Which writer the scenario's draw takes ("cartpole", "model"), "" when a key of it
    has no array form."""
    from tspend.plants.articulated.model_numbers import split
    from tspend.plants.randomize import takes_model_values

    rest = [d.name for d in scenario.randomize if not d.name.startswith("x0[")]
    if scenario.plant.kind == "cartpole_mujoco" and all(n in CARTPOLE_KEYS for n in rest):
        return "cartpole"
    if takes_model_values(scenario.plant) and all(
            (split(n) or ("", ""))[1] in MODEL_QUANTITIES for n in rest):
        return "model"
    return ""


def _cartpole_fields(model: Any, plant: Any, cfg: Any, values: dict,
                     n: int) -> tuple[dict, dict]:
    """Per env: the primary fields the cart-pole keys write, and its [plant] parameters
    (:meth:`tspend.plants.mjcf.ModelFacts.params` with the drawn numbers)."""
    import mujoco

    from tspend.plants.mjcf import AXIAL_INERTIA_RATIO

    p0 = plant.params
    joint = mujoco.mjtObj.mjOBJ_JOINT
    hinge = mujoco.mj_name2id(model, joint, cfg.hinge_joint)
    slide = mujoco.mj_name2id(model, joint, cfg.slide_joint)
    act = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, cfg.actuator)
    pole, cart = int(model.jnt_bodyid[hinge]), int(model.jnt_bodyid[slide])
    drawn = {k: np.broadcast_to(np.asarray(values.get(k, getattr(p0, k)), dtype=float), (n,))
             for k in CARTPOLE_KEYS}
    fields: dict[str, np.ndarray] = {}
    mass = np.repeat(model.body_mass[None], n, axis=0)
    inertia = np.repeat(model.body_inertia[None], n, axis=0)
    ipos = np.repeat(model.body_ipos[None], n, axis=0)
    if "m" in values or "l" in values:
        m, l = drawn["m"], drawn["l"]
        pivot = model.jnt_pos[hinge]
        arm = model.body_ipos[pole] - pivot
        axis = arm / np.linalg.norm(arm)
        J = 4.0 / 3.0 * m * l ** 2
        i_perp = J - m * l ** 2
        mass[:, pole] = m
        ipos[:, pole] = pivot + l[:, None] * axis
        inertia[:, pole] = np.stack([i_perp, i_perp, i_perp * AXIAL_INERTIA_RATIO], axis=1)
    if "M" in values:
        carried = p0.M - float(model.body_mass[cart])
        cart_mass = drawn["M"] - carried
        inertia[:, cart] = model.body_inertia[cart] * (cart_mass / model.body_mass[cart])[:, None]
        mass[:, cart] = cart_mass
    fields.update(body_mass=mass, body_inertia=inertia, body_ipos=ipos)
    if "gear" in values:
        gear = np.repeat(model.actuator_gear[None], n, axis=0)
        gear[:, act, 0] *= drawn["gear"] / p0.gear
        fields["actuator_gear"] = gear
    params = dataclasses.replace(p0, **{k: drawn[k] for k in CARTPOLE_KEYS}, J=0.0)
    table = {k: np.broadcast_to(np.asarray(v, dtype=float), (n,))
             for k, v in dataclasses.asdict(p0).items()}
    table.update({k: drawn[k] for k in CARTPOLE_KEYS}, J=params.pole_inertia_pivot * np.ones(n))
    d_to_tau = params.disturbance_torque * np.ones(n)
    return fields, {"parameters": table, "d_to_tau": d_to_tau}


def _model_fields(model: Any, plant: Any, cfg: Any, values: dict,
                  n: int) -> tuple[dict, dict]:
    """Per env: the fields a model's ``BODY.mass``, ``JOINT.damping``, ``JOINT.armature``
    write, and its parameters (the machine's vector with the drawn numbers)."""
    import mujoco

    from tspend.plants.articulated.model_numbers import split

    params0 = plant.parameters()
    table = {k: np.full(n, v, dtype=float) for k, v in params0.items()}
    fields = {"body_mass": np.repeat(model.body_mass[None], n, axis=0),
              "body_inertia": np.repeat(model.body_inertia[None], n, axis=0),
              "dof_damping": np.repeat(model.dof_damping[None], n, axis=0),
              "dof_armature": np.repeat(model.dof_armature[None], n, axis=0)}
    for name, v in values.items():
        if name.startswith("x0["):
            continue
        element, quantity = split(name)
        if quantity == "mass":
            b = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, element)
            scale = v / model.body_mass[b]
            fields["body_mass"][:, b] = v
            fields["body_inertia"][:, b] = model.body_inertia[b] * scale[:, None]
            for k in range(3):
                if f"{element}.inertia_{k + 1}" in table:
                    table[f"{element}.inertia_{k + 1}"] = model.body_inertia[b, k] * scale
        else:
            j = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, element)
            fields[f"dof_{quantity}"][:, int(model.jnt_dofadr[j])] = v
        table[name] = np.asarray(v, dtype=float)
    # the push per unit d does not depend on these numbers: the first seed's for all
    return fields, {"parameters": table, "d_to_tau": None}


def _derived(model: Any, fields: dict, n: int) -> dict:
    """The fields mj_setConst derives, per env, from each env's primary ``fields``."""
    import mujoco

    work = copy.deepcopy(model)
    data = mujoco.MjData(work)
    out = {k: np.empty((n,) + np.shape(getattr(model, k))) for k in DERIVED if hasattr(model, k)}
    # the scratch model's arrays are views of its memory: taken once, written per env
    writes = [(getattr(work, k), v) for k, v in fields.items()]
    reads = [(getattr(work, k), arr) for k, arr in out.items()]
    set_const = mujoco.mj_setConst
    for e in range(n):
        for view, v in writes:
            view[...] = v[e]
        set_const(work, data)
        for view, arr in reads:
            arr[e] = view
    # the compiler's statistics (not mj_setConst's): the mean of M's diagonal at qpos0,
    # the mean body mass
    mass = fields.get("body_mass", np.broadcast_to(model.body_mass, (n, model.nbody)))
    return {**out, "stat.meaninertia": out["dof_M0"].mean(axis=1),
            "stat.meanmass": mass[:, 1:].mean(axis=1)}


def _reset_map(plant: Any, x0s: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """qpos, qvel per env after the plant's reset to each row of ``x0s``: the reset is an
    affine map of x0, measured at 0 and at each unit vector and checked at the last row
    (None: it is not affine, reset each)."""
    n = x0s.shape[1]

    def state(x0):
        plant.reset(np.asarray(x0, dtype=float))
        return np.concatenate([plant.data.qpos, plant.data.qvel])

    base = state(np.zeros(n))
    cols = np.stack([state(np.eye(n)[i]) - base for i in range(n)], axis=1)
    full = base[None, :] + x0s @ cols.T
    ok = np.array_equal(full[-1], state(x0s[-1]))
    state(x0s[0])
    if not ok:
        full = np.stack([state(x) for x in x0s])
        state(x0s[0])
    nq = plant.data.qpos.size
    return full[:, :nq], full[:, nq:]


def _batched_model(first: Any, per_env: dict) -> tuple[Any, Any]:
    """The first seed's mjx.Model with ``per_env`` fields (name or ``stat.NAME`` -> (N, ...))
    on a leading env axis, and its vmap axes."""
    model, axes = first.model, first.in_axes
    plain = {k: v for k, v in per_env.items() if not k.startswith("stat.")}
    stat = {k[5:]: v for k, v in per_env.items() if k.startswith("stat.")}
    model = model.replace(**plain, stat=model.stat.replace(**stat))
    axes = axes.replace(**{k: 0 for k in plain}, stat=axes.stat.replace(**{k: 0 for k in stat}))
    return model, axes


class DrawnMachines(Sequence):
    """Each env's MachineInfo: the first seed's with the env's parameters and draw, made
    when a row asks for it (a row is written per env anyway; made here, 10^5 records
    took 10 s of the machines' build)."""

    def __init__(self, first: Any, values: dict, table: dict, n: int) -> None:
        m0 = first.machines[0]
        self._kind, self._fields = type(m0), dict(m0.__dict__)
        self._keys, self._names = list(m0.parameters), list(values)
        self._params = np.stack([np.broadcast_to(np.asarray(table.get(k, m0.parameters[k]),
                                                            dtype=float), (n,))
                                 for k in self._keys], axis=1)
        self._drawn = np.stack([values[k] for k in self._names], axis=1) if self._names \
            else np.zeros((n, 0))

    def __len__(self) -> int:
        return self._params.shape[0]

    def __getitem__(self, e: Any) -> Any:
        if isinstance(e, slice):
            return [self[i] for i in range(*e.indices(len(self)))]
        # a copy of the frozen record with two fields replaced (dataclasses.replace would
        # run the constructor and copy.copy the reduce protocol: a tenth of a millisecond)
        m = object.__new__(self._kind)
        m.__dict__.update(self._fields, parameters=dict(zip(self._keys, self._params[e].tolist())),
                          drawn=dict(zip(self._names, self._drawn[e].tolist())))
        return m


def drawn_fleet(scenario: Any, seeds: tuple[int, ...], first: Any) -> Any:
    """The fleet of ``seeds`` from ``first`` (the CPU build of ``seeds[0]``, a one-env
    fleet) and the draw as arrays (module docstring)."""
    n, plant, cfg = len(seeds), first.plant, scenario.plant
    values = draw_values(scenario, seeds)
    writer = _cartpole_fields if array_form(scenario) == "cartpole" else _model_fields
    fields, extra = writer(plant.model, plant, cfg, values, n)
    per_env = {**fields, **_derived(plant.model, fields, n)}
    x0s = np.stack([np.broadcast_to(values.get(f"x0[{i}]", v), (n,))
                    for i, v in enumerate(cfg.x0)], axis=1).astype(float)
    qpos0, qvel0 = _reset_map(plant, x0s)
    model, in_axes = _batched_model(first, per_env)
    d_to_tau = extra["d_to_tau"] if extra["d_to_tau"] is not None else \
        np.full(n, first.d_to_tau[0])

    def tile(a: np.ndarray) -> np.ndarray:
        return np.repeat(a[:1], n, axis=0)

    return dataclasses.replace(
        first, seeds=seeds, model=model, in_axes=in_axes, qpos0=qpos0, qvel0=qvel0,
        d_to_tau=np.asarray(d_to_tau, dtype=float), lo=tile(first.lo), hi=tile(first.hi),
        tasks=first.tasks * n, machines=DrawnMachines(first, values, extra["parameters"], n),
        u_lo=tile(first.u_lo), u_hi=tile(first.u_hi))
