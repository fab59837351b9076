"""The equations of motion of a hinge/slide tree, derived once by Lagrange over CasADi's SX.

For the tree of :mod:`.tree`, with positions ``q``, velocities ``q'`` and the parameter
vector ``p`` (:func:`parameter_table`: masses, centres of mass, principal inertias, body
offsets, joint armature, damping, stiffness and spring reference, the actuators' gear,
gain, bias and ranges, gravity), :func:`derive` builds, following MuJoCo's kinematics
(``mj_kinematics``: a body's frame is its parent's moved by ``body_pos``/``body_quat``,
then each of its joints in order: a slide translates along its axis by ``q - qpos0``, a
hinge turns about its axis through its anchor),

    T(q, q') = sum_b 1/2 m_b |c_b'|^2 + 1/2 w_b^T R_b I_b R_b^T w_b          (1)
    V(q)     = -sum_b m_b g . c_b + sum_j 1/2 k_j (q_j - q_j^spring)^2         (2)

(``c_b`` the body's centre of mass, ``w_b`` its angular velocity, the sum of the axes of
the hinges above it and in it times their rates) and Lagrange's equations

    M(q) q'' = tau(q, q', u) + qfrc - h(q, q'),                                (3)
    M = d^2 T / dq'^2 + diag(armature),
    h = (d/dq (dT/dq')) q' - dT/dq + dV/dq + diag(damping) q',

the derivatives taken by CasADi's algorithmic differentiation on the symbolic graph (no
MuJoCo dynamics is called).  ``tau`` is MuJoCo's actuator law (:class:`.tree.ActuatorFacts`).

From this one graph come: the CasADi functions (:attr:`Derivation.dynamics`, with and
without the actuator's clips) that MPC, linearisation and identification use, and Python
source for numba (:func:`python_source`: the graph's instructions written out one per
line), compiled with ``cache=True`` into a module in the derivation cache
(:func:`cache_dir`), so a second process loads the compiled machine code from disk.
"""

from __future__ import annotations

import hashlib
import importlib.util
import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

from tspend.plants.articulated.tree import Tree

__all__ = ["Derivation", "derive", "parameter_table", "python_source", "cache_dir",
           "compiled_module", "jax_functions", "jax_function_at", "GENERATOR_VERSION"]

#: bumped whenever the generated code changes shape (part of the cache key)
GENERATOR_VERSION = "4"


def parameter_table(tree: Tree) -> tuple[tuple[str, ...], np.ndarray]:
    """``(names, values)`` of the parameter vector ``p`` of ``tree``'s equations: what a
    randomised draw, an identification or an override changes without a new derivation."""
    names: list[str] = []
    values: list[float] = []

    def add(name: str, v: float) -> None:
        names.append(name)
        values.append(float(v))

    for b in tree.bodies:
        add(f"{b.name}.mass", b.mass)
        for axis, v in zip("xyz", b.ipos):
            add(f"{b.name}.ipos_{axis}", v)
        for k, v in enumerate(b.inertia):
            add(f"{b.name}.inertia_{k + 1}", v)
        for axis, v in zip("xyz", b.pos):
            add(f"{b.name}.pos_{axis}", v)
    for j in tree.joints:
        add(f"{j.name}.armature", j.armature)
        add(f"{j.name}.damping", j.damping)
        add(f"{j.name}.stiffness", j.stiffness)
        add(f"{j.name}.springref", j.springref)
        if j.actfrcrange is not None:
            add(f"{j.name}.actfrc_lo", j.actfrcrange[0])
            add(f"{j.name}.actfrc_hi", j.actfrcrange[1])
    for a in tree.actuators:
        add(f"{a.name}.gear", a.gear)
        for k, v in enumerate(a.gain):
            add(f"{a.name}.gain{k}", v)
        for k, v in enumerate(a.bias):
            add(f"{a.name}.bias{k}", v)
        if a.ctrlrange is not None:
            add(f"{a.name}.ctrl_lo", a.ctrlrange[0])
            add(f"{a.name}.ctrl_hi", a.ctrlrange[1])
        if a.forcerange is not None:
            add(f"{a.name}.force_lo", a.forcerange[0])
            add(f"{a.name}.force_hi", a.forcerange[1])
    for axis, v in zip("xyz", tree.gravity):
        add(f"gravity_{axis}", v)
    return tuple(names), np.array(values, dtype=float)


def _quat_matrix(q: tuple[float, ...]) -> np.ndarray:
    w, x, y, z = q
    n = math.sqrt(w * w + x * x + y * y + z * z)
    w, x, y, z = w / n, x / n, y / n, z / n
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


@dataclass
class Derivation:
    """One tree's equations (3) as CasADi functions of ``(q, q', u, qfrc, p)``:
    ``dynamics`` -> ``(M, rhs)`` with the actuator's clips, ``dynamics_free`` without
    them (smooth, for optimisers), ``energy`` -> ``(T, V)``; ``names``/``nominal`` the
    parameter vector."""

    tree: Tree
    names: tuple[str, ...]
    nominal: np.ndarray
    dynamics: Any
    dynamics_free: Any
    energy: Any
    kinematics: Any

    @property
    def nv(self) -> int:
        return self.tree.nv

    @property
    def nu(self) -> int:
        return len(self.tree.actuators)

    def key(self) -> str:
        return structure_cache_key(self.tree)


def structure_cache_key(tree: Tree) -> str:
    """The cache key of ``tree``'s generated module: the generator's version and the tree's
    structure (its numbers are the parameter vector, not part of the code)."""
    return hashlib.sha256(f"{GENERATOR_VERSION}:{tree.structure_key()}".encode()).hexdigest()[:24]


def derive(tree: Tree) -> Derivation:
    """Derive equations (1)-(3) of ``tree`` over CasADi's SX (module docstring)."""
    import casadi as ca

    if tree.refusals:
        raise ValueError("; ".join(tree.refusals))
    nv, nu = tree.nv, len(tree.actuators)
    names, nominal = parameter_table(tree)
    P = {name: i for i, name in enumerate(names)}
    q, qd = ca.SX.sym("q", nv), ca.SX.sym("qd", nv)
    u, qfrc = ca.SX.sym("u", nu), ca.SX.sym("qfrc", nv)
    p = ca.SX.sym("p", len(names))

    def par(name: str) -> Any:
        return p[P[name]]

    def vec(prefix: str) -> Any:
        return ca.vertcat(par(f"{prefix}_x"), par(f"{prefix}_y"), par(f"{prefix}_z"))

    def rotation(axis: tuple[float, ...], angle: Any) -> Any:
        # Rodrigues' formula about a unit axis (MuJoCo normalises jnt_axis when compiling)
        a = np.asarray(axis, dtype=float)
        a = a / np.linalg.norm(a)
        K = ca.DM([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
        return ca.DM.eye(3) + ca.sin(angle) * K + (1.0 - ca.cos(angle)) * ca.mtimes(K, K)

    gravity = vec("gravity")
    frames: list[tuple[Any, Any, Any]] = []   # per body: R, x, omega
    T = ca.SX(0.0)
    V = ca.SX(0.0)
    coms = []
    for b in tree.bodies:
        if b.parent < 0:
            Rp, xp, wp = ca.SX.eye(3), ca.SX.zeros(3), ca.SX.zeros(3)
        else:
            Rp, xp, wp = frames[b.parent]
        x = xp + ca.mtimes(Rp, vec(f"{b.name}.pos"))
        R = ca.mtimes(Rp, ca.DM(_quat_matrix(b.quat)))
        w = wp
        for j in b.joints:
            jf = tree.joints[j]
            anchor = ca.DM(jf.anchor)
            axis_w = ca.mtimes(R, ca.DM(jf.axis) / float(np.linalg.norm(jf.axis)))
            if jf.kind == "slide":
                x = x + axis_w * (q[j] - jf.qpos0)
            else:
                anchor_w = x + ca.mtimes(R, anchor)
                R = ca.mtimes(R, rotation(jf.axis, q[j] - jf.qpos0))
                x = anchor_w - ca.mtimes(R, anchor)
                w = w + axis_w * qd[j]
        frames.append((R, x, w))
        c = x + ca.mtimes(R, vec(f"{b.name}.ipos"))
        coms.append(c)
        Ri = ca.mtimes(R, ca.DM(_quat_matrix(b.iquat)))
        I_body = ca.diag(ca.vertcat(par(f"{b.name}.inertia_1"), par(f"{b.name}.inertia_2"),
                                    par(f"{b.name}.inertia_3")))
        Iw = ca.mtimes([Ri, I_body, Ri.T])
        cd = ca.mtimes(ca.jacobian(c, q), qd)
        m = par(f"{b.name}.mass")
        T = T + 0.5 * m * ca.dot(cd, cd) + 0.5 * ca.mtimes([w.T, Iw, w])
        V = V - m * ca.dot(gravity, c)
    for j, jf in enumerate(tree.joints):
        V = V + 0.5 * par(f"{jf.name}.stiffness") * (q[j] - par(f"{jf.name}.springref")) ** 2

    T_qd = ca.gradient(T, qd)
    M = ca.jacobian(T_qd, qd) + ca.diag(ca.vertcat(*[par(f"{jf.name}.armature") for jf in tree.joints]))
    damping = ca.vertcat(*[par(f"{jf.name}.damping") * qd[j] for j, jf in enumerate(tree.joints)])
    h = ca.mtimes(ca.jacobian(T_qd, q), qd) - ca.gradient(T, q) + ca.gradient(V, q) + damping

    def actuation(clamp: bool) -> Any:
        tau = [ca.SX(0.0)] * nv
        for k, a in enumerate(tree.actuators):
            gear = par(f"{a.name}.gear")
            L, Vel = gear * q[a.joint], gear * qd[a.joint]
            uk = u[k]
            if clamp and a.ctrlrange is not None:
                uk = ca.fmin(ca.fmax(uk, par(f"{a.name}.ctrl_lo")), par(f"{a.name}.ctrl_hi"))
            gain = par(f"{a.name}.gain0") + par(f"{a.name}.gain1") * L + par(f"{a.name}.gain2") * Vel
            f = gain * uk + par(f"{a.name}.bias0") + par(f"{a.name}.bias1") * L + par(f"{a.name}.bias2") * Vel
            if clamp and a.forcerange is not None:
                f = ca.fmin(ca.fmax(f, par(f"{a.name}.force_lo")), par(f"{a.name}.force_hi"))
            tau[a.joint] = tau[a.joint] + gear * f
        if clamp:  # MuJoCo clamps the joint's total actuator force (actuatorfrcrange)
            for j, jf in enumerate(tree.joints):
                if jf.actfrcrange is not None:
                    tau[j] = ca.fmin(ca.fmax(tau[j], par(f"{jf.name}.actfrc_lo")),
                                     par(f"{jf.name}.actfrc_hi"))
        return ca.vertcat(*tau) if nv else ca.SX.zeros(0)

    M_flat = ca.reshape(M, nv * nv, 1)
    args = [q, qd, u, qfrc, p]
    arg_names = ["q", "qd", "u", "qfrc", "p"]
    # common subexpressions merged (AD repeats the kinematics' products many times): the
    # generated code is several times shorter, and so numba's compile
    dyn = ca.Function("articulated_dynamics", args,
                      ca.cse([M_flat, actuation(True) + qfrc - h]), arg_names, ["M", "rhs"])
    dyn_free = ca.Function("articulated_dynamics_free", args,
                           ca.cse([M_flat, actuation(False) + qfrc - h]), arg_names, ["M", "rhs"])
    energy = ca.Function("articulated_energy", [q, qd, p], [T, V], ["q", "qd", "p"], ["T", "V"])
    kin = ca.Function("articulated_coms", [q, p], [ca.horzcat(*coms)] if coms else [ca.SX.zeros(3, 0)],
                      ["q", "p"], ["coms"])
    return Derivation(tree, names, nominal, dyn, dyn_free, energy, kin)


# -- CasADi's instructions as Python ---------------------------------------------------
def _ops() -> dict[int, str]:
    import casadi as ca

    binary = {"ADD": "{0} + {1}", "SUB": "{0} - {1}", "MUL": "{0} * {1}", "DIV": "{0} / {1}",
              "POW": "{0} ** {1}", "CONSTPOW": "{0} ** {1}", "FMIN": "min({0}, {1})",
              "FMAX": "max({0}, {1})", "ATAN2": "math.atan2({0}, {1})"}
    unary = {"NEG": "-{0}", "SQ": "{0} * {0}", "TWICE": "2.0 * {0}", "INV": "1.0 / {0}",
             "SQRT": "math.sqrt({0})", "SIN": "math.sin({0})", "COS": "math.cos({0})",
             "TAN": "math.tan({0})", "EXP": "math.exp({0})", "LOG": "math.log({0})",
             "FABS": "abs({0})", "TANH": "math.tanh({0})", "ASSIGN": "{0}",
             "SIGN": "(1.0 if {0} > 0.0 else (-1.0 if {0} < 0.0 else 0.0))"}
    out = {}
    for name, fmt in {**binary, **unary}.items():
        code = getattr(ca, f"OP_{name}", None)
        if code is not None:
            out[int(code)] = fmt
    return out


def python_source(fn: Any, name: str, arg_names: tuple[str, ...], out_names: tuple[str, ...]) -> str:
    """A straight-line Python function ``name(*arg_names, *out_names)`` computing the SX
    function ``fn`` instruction by instruction (inputs read by index, outputs written by
    index: dense vectors), which numba compiles."""
    import casadi as ca

    ops = _ops()
    lines = [f"def {name}({', '.join(arg_names + out_names)}):"]
    for k in range(fn.n_instructions()):
        op = int(fn.instruction_id(k))
        o = fn.instruction_output(k)
        i = fn.instruction_input(k)
        if op == int(ca.OP_INPUT):
            lines.append(f"    w{o[0]} = {arg_names[i[0]]}[{i[1]}]")
        elif op == int(ca.OP_OUTPUT):
            lines.append(f"    {out_names[o[0]]}[{o[1]}] = w{i[0]}")
        elif op == int(ca.OP_CONST):
            lines.append(f"    w{o[0]} = {float(fn.instruction_constant(k))!r}")
        elif op in ops:
            lines.append(f"    w{o[0]} = " + ops[op].format(*(f"w{v}" for v in i)))
        else:
            raise ValueError(f"CasADi operation {op} has no Python form")
    lines.append("    return")
    return "\n".join(lines) + "\n"


_SOLVE = '''
@njit(cache=True)
def rhs(s, u, qfrc, p, M, r, sdot):
    """s' = [q', q''] of equations (3): M q'' = rhs solved by Cholesky (M is SPD)."""
    n = NV
    dynamics(s[:n], s[n:], u, qfrc, p, M, r)
    # Cholesky in place: M (column-major n x n) = L L^T, lower triangle
    for j in range(n):
        acc = M[j + j * n]
        for k in range(j):
            acc -= M[j + k * n] * M[j + k * n]
        d = math.sqrt(acc)
        M[j + j * n] = d
        for i in range(j + 1, n):
            acc = M[i + j * n]
            for k in range(j):
                acc -= M[i + k * n] * M[j + k * n]
            M[i + j * n] = acc / d
    for i in range(n):
        acc = r[i]
        for k in range(i):
            acc -= M[i + k * n] * r[k]
        r[i] = acc / M[i + i * n]
    for i in range(n - 1, -1, -1):
        acc = r[i]
        for k in range(i + 1, n):
            acc -= M[k + i * n] * r[k]
        r[i] = acc / M[i + i * n]
    for i in range(n):
        sdot[i] = s[n + i]
        sdot[n + i] = r[i]


_PTR = types.CPointer(types.float64)


@cfunc(types.void(_PTR, _PTR, _PTR, _PTR, _PTR, _PTR, _PTR), cache=True)
def rhs_c(s, u, qfrc, p, M, r, sdot):
    """:func:`rhs` over C pointers: its address is what a compiled closed loop calls,
    whatever the structure (so one cached loop serves every derived machine)."""
    n = NV
    rhs(carray(s, (2 * n,)), carray(u, (NU,)), carray(qfrc, (n,)), carray(p, (NP,)),
        carray(M, (n * n,)), carray(r, (n,)), carray(sdot, (2 * n,)))


@cfunc(types.void(_PTR, _PTR, _PTR, _PTR, _PTR), cache=True)
def energy_c(q, qd, p, T, V):
    """:func:`energy` over C pointers (the swing-up's energy in compiled loops)."""
    energy(carray(q, (NV,)), carray(qd, (NV,)), carray(p, (NP,)), carray(T, (1,)), carray(V, (1,)))
'''


def module_source(d: Derivation) -> str:
    """The generated module of ``d``: ``dynamics`` (equations (3) with the clips),
    ``dynamics_free``, ``energy`` (T and V of (1)-(2)) and ``rhs`` (the state derivative),
    each numba-compiled and cached, and ``rhs_c``, ``energy_c``: C entry points of
    ``rhs`` and ``energy`` for compiled loops."""
    args, outs = ("q", "qd", "u", "qfrc", "p"), ("M", "r")
    head = (f'"""Generated by tspend.plants.articulated.derive (version {GENERATOR_VERSION}) from '
            f'a tree of {d.nv} joints: {", ".join(d.tree.joint_names)}. Do not edit."""\n'
            "import math\nfrom numba import carray, cfunc, njit, types\n\n"
            f"NV = {d.nv}\nNU = {d.nu}\nNP = {len(d.names)}\n\n")
    body = ("@njit(cache=True)\n" + python_source(d.dynamics, "dynamics", args, outs) + "\n\n"
            + "@njit(cache=True)\n" + python_source(d.dynamics_free, "dynamics_free", args, outs)
            + "\n\n@njit(cache=True)\n"
            + python_source(d.energy, "energy", ("q", "qd", "p"), ("T", "V")))
    return head + body + "\n" + _SOLVE


def cache_dir() -> Path | None:
    """Where derivations are kept: ``$TSPEND_CACHE_DIR``, else ``$XDG_CACHE_HOME/tspend``,
    else ``~/.cache/tspend``; None when none of them can be written (then each process
    derives and compiles anew)."""
    from tspend.runtime.jit import writable_cache

    return writable_cache("articulated")


_LOADED: dict[str, Any] = {}


def compiled_module(tree: Tree, derivation: Callable[[], Derivation]) -> Any:
    """The numba module of ``tree``: imported from the cache when its source is there (no
    derivation at all), else derived (``derivation()``), written there (atomically) and
    imported; in a temporary folder without a cache."""
    key = structure_cache_key(tree)
    if key in _LOADED:
        return _LOADED[key]
    from tspend.runtime import cache

    folder = cache_dir()
    if folder is None:  # removed when this process ends: nothing left in the temp folder
        folder = cache.private_folder("tspend-articulated-")
    path = folder / f"tspend_articulated_{key}.py"
    # checked before it is imported: its key (another machine's module would index this
    # one's arrays out of bounds) and its checksum; numba's files for it likewise
    problem = cache.text_problem(path, key)
    if problem is not None:
        if problem != "missing":
            cache.rebuilt("derivation", path, problem)
            cache.discard(path)
        cache.write_atomically(path, cache.stamped(module_source(derivation()), key).encode())
    cache.check_numba_files(folder / "__pycache__", f"tspend_articulated_{key}.",
                            "compiled derivation")
    name = f"tspend_articulated_{key}"
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    spec.loader.exec_module(module)
    _LOADED[key] = module
    return module


#: the generated functions a JAX form runs (:func:`jax_functions`), by their C entry's name
_C_ENTRIES = {"rhs_c": "rhs", "energy_c": "energy"}
#: :func:`jax_functions` of each loaded module, by the module's name
_JAX_BUILDS: dict[str, dict[str, Callable]] = {}


def jax_functions(module: Any) -> dict[str, Callable]:
    """The generated ``module``'s functions built over ``jax.numpy`` from its own source
    file: the very statements numba compiled (:func:`module_source`), decorators dropped,
    ``math`` bound to ``jax.numpy``'s functions and ``min``/``max`` to selects with
    Python's (and numba's) choice.  They write their outputs in place, so they are called
    on :class:`~tspend.runtime.law.Slots`."""
    import ast

    import jax.numpy as jnp

    from tspend.runtime.law import jax_math

    if module.__name__ in _JAX_BUILDS:
        return _JAX_BUILDS[module.__name__]
    tree = ast.parse(Path(module.__file__).read_text(encoding="utf-8"))
    kept = []
    for node in tree.body:
        if isinstance(node, ast.FunctionDef) and not node.name.endswith("_c"):
            node.decorator_list = []
            kept.append(node)
        elif isinstance(node, ast.Assign) and all(isinstance(t, ast.Name) and t.id.isupper()
                                                  and not t.id.startswith("_")
                                                  for t in node.targets):
            kept.append(node)           # NV, NU, NP
    scope: dict[str, Any] = {"math": jax_math(),
                             "min": lambda a, b: jnp.where(b < a, b, a),
                             "max": lambda a, b: jnp.where(b > a, b, a)}
    exec(compile(ast.Module(body=kept, type_ignores=[]), module.__file__, "exec"), scope)
    built = {name: scope[name] for name in ("dynamics", "dynamics_free", "energy", "rhs")}
    _JAX_BUILDS[module.__name__] = built
    return built


def jax_function_at(fn: Any) -> Callable:
    """The JAX build (:func:`jax_functions`) of the generated function whose numba C entry
    (``rhs_c``, ``energy_c`` of a loaded module) the ctypes function ``fn`` calls."""
    import ctypes

    address = ctypes.cast(fn, ctypes.c_void_p).value
    for module in _LOADED.values():
        for entry, name in _C_ENTRIES.items():
            if getattr(module, entry).address == address:
                return jax_functions(module)[name]
    raise LookupError(f"no loaded derivation has a C entry at {address:#x}")
