"""The numbers of an MJCF a scenario may replace, named by the model's own body and joint
names: what ``[randomize]`` draws on the machines read from their MJCF (the articulated
and the Furuta kinds, :mod:`tspend.plants.randomize`).

A name is ``ELEMENT.QUANTITY``:

* ``BODY.mass``: the body's mass, kg; its inertia is scaled with it (the radius of
  gyration and the centre of mass stay: a denser body of the same shape);
* ``JOINT.damping``: the joint's viscous damping (the linear term), N s/m or N m s/rad;
* ``JOINT.armature``: the joint's armature (inertia added to its diagonal of the mass
  matrix), kg or kg m^2.

:func:`write_values` writes them into the model's ``mujoco.MjSpec`` before it compiles
(the one place they are written: both backends are built from that compiled model, the
derived ODE reading its numbers into its parameter vector, so a drawn number never asks
for another derivation); :func:`check_values` reads the compiled model back (a value
that did not take is an error).  A body whose inertial is explicit gets its ``mass``,
``inertia`` (and ``fullinertia``) scaled; one whose mass comes from its geoms (the
compiler's ``inertiafromgeom``) gets its geoms' masses or densities scaled: either way
by the drawn mass over the compiled one.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from tspend.runtime.errors import ScenarioError

__all__ = ["QUANTITIES", "LOWER_BOUNDS", "split", "model_values", "write_values", "check_values", "compile_with_values",
           "check_names"]

#: the quantities a name may end with, and the kind of element each belongs to
QUANTITIES = {"mass": "body", "damping": "joint", "armature": "joint"}
#: the lower bound of each quantity and whether it is strict (a mass > 0, the others >= 0)
LOWER_BOUNDS = {"mass": (0.0, True), "damping": (0.0, False), "armature": (0.0, False)}
#: relative agreement the compiled model must show with a written value
_TOOK = 1e-9


def split(name: str) -> tuple[str, str] | None:
    """``(element, quantity)`` of ``ELEMENT.QUANTITY``; None when ``name`` is not one."""
    element, dot, quantity = name.rpartition(".")
    if not dot or not element or quantity not in QUANTITIES:
        return None
    return element, quantity


def model_values(model: Any) -> dict[str, float]:
    """Every name of the compiled ``model`` that may be replaced, with its value there."""
    out: dict[str, float] = {}
    for b in range(1, model.nbody):
        name = model.body(b).name
        if name:
            out[f"{name}.mass"] = float(model.body_mass[b])
    for j in range(model.njnt):
        name = model.joint(j).name
        if name:
            dof = int(model.jnt_dofadr[j])
            out[f"{name}.damping"] = float(model.dof_damping[dof])
            out[f"{name}.armature"] = float(model.dof_armature[dof])
    return out


def check_names(names: Any, known: dict[str, float], where: str, prefix: str = "randomize.") -> None:
    """ScenarioError, naming the bodies and joints there are, for a name of ``names`` that
    is not one of ``known`` (:func:`model_values` of the model)."""
    for name in names:
        if name in known:
            continue
        bodies = [n[:-len(".mass")] for n in known if n.endswith(".mass")]
        joints = [n[:-len(".damping")] for n in known if n.endswith(".damping")]
        parts = split(name)
        kind = QUANTITIES[parts[1]] if parts else "body or joint"
        raise ScenarioError(
            f"{where}: {prefix}{name}: the model has no {kind} {parts[0] if parts else name!r}; "
            f"allowed: BODY.mass for bodies {', '.join(bodies) or 'none'}; JOINT.damping and "
            f"JOINT.armature for joints {', '.join(joints) or 'none'}")


def write_values(spec: Any, values: tuple[tuple[str, float], ...], where: str) -> None:
    """Write ``(name, value)`` pairs into ``spec`` before it compiles (module docstring).

    A mass is written as a scale of what the body has: the model compiled once as it is
    gives the current mass (the ratio's denominator)."""
    if not values:
        return
    import mujoco

    # compiling leaves the spec editable
    compiled = spec.compile() if any(n.endswith(".mass") for n, _ in values) else None
    from_geoms = spec.compiler.inertiafromgeom
    for name, value in values:
        element, quantity = split(name) or ("", "")
        if quantity == "mass":
            body = spec.body(element)
            b = mujoco.mj_name2id(compiled, mujoco.mjtObj.mjOBJ_BODY, element)
            if body is None or b < 0:
                raise ScenarioError(f"{where}: randomize.{name}: the model has no body {element!r}")
            now = float(compiled.body_mass[b])
            if not now > 0.0:
                raise ScenarioError(f"{where}: randomize.{name}: the body has no mass to scale "
                                    f"(its compiled mass is {now:g})")
            scale = float(value) / now
            explicit = body.explicitinertial and \
                from_geoms != mujoco.mjtInertiaFromGeom.mjINERTIAFROMGEOM_TRUE
            if explicit:
                body.mass = float(value)
                body.inertia = np.asarray(body.inertia, dtype=float) * scale
                full = np.asarray(body.fullinertia, dtype=float)
                if not math.isnan(full[0]):
                    body.fullinertia = full * scale
            else:
                for geom in body.geoms:
                    if math.isnan(float(geom.mass)):
                        geom.density = float(geom.density) * scale
                    else:
                        geom.mass = float(geom.mass) * scale
        elif quantity in ("damping", "armature"):
            joint = spec.joint(element)
            if joint is None:
                raise ScenarioError(f"{where}: randomize.{name}: the model has no joint {element!r}")
            if quantity == "damping":
                # MuJoCo 4's damping is [linear, polynomial terms]: only the linear one set
                damping = np.array(joint.damping, dtype=float)
                damping[0] = float(value)
                joint.damping = damping
            else:
                joint.armature = float(value)
        else:
            raise ScenarioError(f"{where}: randomize.{name}: not BODY.mass, JOINT.damping or "
                                f"JOINT.armature")


def check_values(model: Any, values: tuple[tuple[str, float], ...], where: str) -> None:
    """ScenarioError when a written value is not what the compiled ``model`` has."""
    if not values:
        return
    got = model_values(model)
    for name, value in values:
        have = got.get(name, math.nan)
        if not abs(have - value) <= _TOOK * max(abs(value), 1e-300):
            raise ScenarioError(f"{where}: randomize.{name}: written {value:.17g}, but the "
                                f"compiled model has {have:.17g}")


def compile_with_values(spec: Any, values: tuple[tuple[str, float], ...], where: str) -> Any:
    """``spec`` with ``values`` written in (:func:`write_values`), compiled and checked
    (:func:`check_values`); ScenarioError when MuJoCo refuses it, naming the values drawn."""
    try:
        write_values(spec, values, where)
        model = spec.compile()
    except ValueError as exc:
        drawn = f" (with {', '.join(f'{n} = {v:g}' for n, v in values)} drawn)" if values else ""
        raise ScenarioError(f"{where}: cannot compile MJCF{drawn}: {exc}") from exc
    check_values(model, values, where)
    return model
