"""Reading a user's MJCF file within the size bounds (docs/reliability.md): :func:`read_spec`
is the one door every model comes in by (the plants, ``tspend inspect``, a run's check of
its model), so every size is checked before MuJoCo allocates it."""

from __future__ import annotations

import os
import stat
import xml.etree.ElementTree as ET

import mujoco
import numpy as np

from tspend.runtime.errors import ScenarioError
from tspend.runtime.bounds import MAX_BODIES, MAX_HFIELD_CELLS, MAX_MODEL_BYTES

__all__ = ["read_spec"]


def read_spec(path: "str | os.PathLike[str]") -> mujoco.MjSpec:
    """Parse an MJCF file within the size bounds (docs/reliability.md): the file size is
    checked before MuJoCo reads it, the heightfields and bodies before it compiles.

    Raises
    ------
    ScenarioError
        no such file, larger than :data:`~tspend.runtime.bounds.MAX_MODEL_BYTES`, not
        parseable, a heightfield of more than ``MAX_HFIELD_CELLS`` cells, or more than
        ``MAX_BODIES`` bodies.
    """
    where = str(path)
    try:
        st = os.stat(path)
    except (OSError, ValueError):
        raise ScenarioError(f"{where}: model file not found") from None
    if not stat.S_ISREG(st.st_mode):
        raise ScenarioError(f"{where}: not a regular file (an MJCF model file is expected)")
    size = st.st_size
    if size > MAX_MODEL_BYTES:
        raise ScenarioError(f"{where}: the model file is {size} bytes, more than "
                            f"{MAX_MODEL_BYTES}")
    _check_xml_sizes(path, where)  # MuJoCo allocates a heightfield as it parses
    try:
        spec = mujoco.MjSpec.from_file(where)
    except (ValueError, OSError) as exc:
        raise ScenarioError(f"{where}: cannot parse MJCF: {' '.join(str(exc).split())}") \
            from None
    for hfield in spec.hfields:
        cells = int(hfield.nrow) * int(hfield.ncol)
        if cells > MAX_HFIELD_CELLS:
            raise ScenarioError(f"{where}: heightfield {hfield.name!r} has {hfield.nrow} x "
                                f"{hfield.ncol} = {cells} cells, more than {MAX_HFIELD_CELLS}")
    bodies = len(spec.bodies)
    if bodies > MAX_BODIES:
        raise ScenarioError(f"{where}: {bodies} bodies, more than {MAX_BODIES}")
    _check_physical_values(spec, where)
    return spec


#: the physical values of an MJCF that must be finite (an unset one is NaN in MjSpec), and
#: those of them that must not be negative
_PHYSICAL = (("bodies", "body", ("mass", "inertia", "fullinertia", "ipos"), ("mass",)),
             ("geoms", "geom", ("mass", "density", "size"), ("mass", "density")),
             ("joints", "joint", ("damping", "armature", "stiffness", "frictionloss", "range"),
              ("damping", "armature", "frictionloss")),
             ("actuators", "actuator", ("gear", "gainprm", "biasprm", "ctrlrange"), ()))


def _check_physical_values(spec: "mujoco.MjSpec", where: str) -> None:
    """An infinite mass, inertia, damping, gear, ... (or a negative mass) is refused here,
    in one line naming it, before the equations built from it fail inside a solver."""
    for collection, label, names, nonnegative in _PHYSICAL:
        for element in getattr(spec, collection):
            for name in names:
                try:
                    values = np.asarray(getattr(element, name), dtype=float).ravel()
                except (AttributeError, TypeError, ValueError):
                    continue
                if np.isinf(values).any() or (name in nonnegative and (values < 0).any()):
                    shown = " ".join(f"{v:g}" for v in values[:6])
                    need = "finite and >= 0" if name in nonnegative else "finite"
                    raise ScenarioError(f"{where}: {label} {element.name or '(unnamed)'!r}: "
                                        f"{name} = {shown}: must be {need}")


def _check_xml_sizes(path: "str | os.PathLike[str]", where: str, depth: int = 0) -> None:
    """The sizes MuJoCo would allocate as it parses, read from the XML text first: each
    heightfield's ``nrow`` x ``ncol``, the bodies, and the same in included files."""
    if depth > 8:
        raise ScenarioError(f"{where}: includes nested more than 8 deep")
    bodies = 0
    try:
        for _, element in ET.iterparse(os.fspath(path), events=("start",)):
            tag = element.tag
            if tag == "body":
                bodies += 1
                if bodies > MAX_BODIES:
                    raise ScenarioError(f"{where}: more than {MAX_BODIES} bodies")
            elif tag == "hfield":
                try:
                    nrow = int(element.get("nrow", "0"))
                    ncol = int(element.get("ncol", "0"))
                except ValueError:
                    continue  # MuJoCo reports it
                if nrow * ncol > MAX_HFIELD_CELLS:
                    raise ScenarioError(f"{where}: heightfield {element.get('name', '')!r} has "
                                        f"{nrow} x {ncol} = {nrow * ncol} cells, more than "
                                        f"{MAX_HFIELD_CELLS}")
            elif tag == "include" and element.get("file"):
                included = os.path.join(os.path.dirname(os.fspath(path)), element.get("file"))
                try:
                    size = os.stat(included).st_size
                except OSError:
                    continue  # MuJoCo reports it
                if size > MAX_MODEL_BYTES:
                    raise ScenarioError(f"{where}: included file {element.get('file')} is "
                                        f"{size} bytes, more than {MAX_MODEL_BYTES}")
                _check_xml_sizes(included, where, depth + 1)
    except ET.ParseError:
        return  # not XML: MuJoCo's parser says why
    except RecursionError:
        raise ScenarioError(f"{where}: XML nested too deeply") from None
