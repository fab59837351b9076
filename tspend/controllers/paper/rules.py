"""The grid rule base: every combination of the inputs' terms is a rule, eq. (8)-(12), compiled.

Rule i fires with ``g^i = prod_j mu_{F_j^i}(z_j)``; normalised by ``varpi``, the sum over
rules, it is ``w^i`` (12).  On a grid ``varpi`` is the product of the inputs' membership
sums, so it costs nothing extra.  Rules are numbered in C order of the grid (the last
input varies fastest): rule i uses term ``term_index[i, j]`` of input j.

The weighted output of any per-rule quantity ``y^i`` is ``y = sum_i w^i y^i``; its
gradient with respect to one membership value (the chain rule behind eq. (11),
docs/paper-notes.md section 4) is
``dy/dmu_{F_j^s} = sum_{i uses F_j^s} (y^i - y) w^i / mu_{F_j^s}``, where
``w^i / mu_{F_j^s}`` is the product of the rule's *other* memberships over ``varpi``
(never a division by a membership).  Carried to the control points:
``dy/dc_{s,l} = dy/dmu_s N_l`` where the set is unsaturated (:func:`tspend.controllers.paper.bspline.unsaturated`).

Guard against ``varpi -> 0`` (every set of some input at zero, possible once control
points adapt): the weights are ``(g^i + eps/h) / (varpi + eps)``, which is the plain
(12) to within ``eps = 1e-12`` when any rule fires and uniform when none does.  The
gradient is the exact gradient of this guarded form.

:class:`Grid` holds a rule base's constants, :class:`Firing` its scratch for one
evaluation; the control points ``C`` (m, T_max, r) are adapted state and live with the
controller's other parameters.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
from numba import njit

import tspend.runtime.xp as xp
from tspend.runtime.law import array_law
from tspend.runtime.jit import JIT
from tspend.controllers.paper.bspline import (BSplineInput, basis_values, membership_curves,
    membership_values, peak_windows, project_unimodal, unsaturated)

#: regularisation of the normalisation (12); see the module docstring
VARPI_EPS = 1e-12


class Grid(NamedTuple):
    """Constants of one grid rule base over m inputs (shared order and control-point count)."""

    knots: np.ndarray        # (m, points + order) knot vector (1) of each input
    terms: np.ndarray        # (m,) number of sets of each input
    term_index: np.ndarray   # (h, m) the term of each input used by each rule
    peak_windows: np.ndarray  # (m, T_max, 2) control points where each set may peak
    points: int              # control points per set
    order: int               # B-spline order d
    eps: float               # the guard of (12)
    shape_projection: bool   # keep every set unimodal and the sets ordered


class Firing(NamedTuple):
    """Scratch of one evaluation of a rule base (written by :func:`fire` and the laws)."""

    z: np.ndarray            # (m,) the inputs, as given (the basis clamps them)
    basis: np.ndarray        # (m, order) nonzero basis functions of each input
    span: np.ndarray         # (m,) knot span of each input
    mu: np.ndarray           # (m, T_max) memberships (5)
    dmu: np.ndarray          # (m, T_max) dy/dmu (11) of the last output differentiated
    w: np.ndarray            # (h,) normalised firing strengths (12)
    y: np.ndarray            # (h,) per-rule outputs y^i to differentiate


def term_index(shape: tuple[int, ...]) -> np.ndarray:
    """(h, m): the term of each input used by each rule, rules in C order of the grid."""
    return np.indices(shape).reshape(len(shape), -1).T.astype(np.int64)


def initial_control_points(inputs: tuple[BSplineInput, ...]) -> np.ndarray:
    """Every input's initial control points in one (m, T_max, r) array (unused rows zero)."""
    C = np.zeros((len(inputs), max(i.terms for i in inputs), inputs[0].control_points))
    for j, inp in enumerate(inputs):
        C[j, : inp.terms] = inp.initial_control_points()
    return C


def grid(inputs: tuple[BSplineInput, ...], shape_projection: bool = False) -> Grid:
    """The constants of the grid rule base over ``inputs``."""
    if not inputs:
        raise ValueError("a rule base needs at least one input")
    if len({(i.control_points, i.order) for i in inputs}) != 1:
        raise ValueError("the inputs of one rule base share the B-spline order and point count")
    C = initial_control_points(inputs)
    windows = np.zeros(C.shape[:2] + (2,), dtype=np.int64)
    for j, inp in enumerate(inputs):
        windows[j, : inp.terms] = peak_windows(C[j, : inp.terms])
    return Grid(knots=np.array([i.knots for i in inputs]),
                terms=np.array([i.terms for i in inputs], dtype=np.int64),
                term_index=term_index(tuple(i.terms for i in inputs)),
                peak_windows=windows, points=inputs[0].control_points,
                order=inputs[0].order, eps=VARPI_EPS, shape_projection=shape_projection)


def firing(g: Grid) -> Firing:
    """Fresh scratch for one rule base."""
    m, T = g.peak_windows.shape[:2]
    h = g.term_index.shape[0]
    return Firing(z=np.zeros(m), basis=np.zeros((m, g.order)), span=np.zeros(m, dtype=np.int64),
                  mu=np.zeros((m, T)), dmu=np.zeros((m, T)), w=np.zeros(h), y=np.zeros(h))


@array_law
def with_inputs(f: Firing, z: np.ndarray) -> Firing:
    """``f`` with the inputs ``z``."""
    return Firing(z, f.basis, f.span, f.mu, f.dmu, f.w, f.y)


@array_law
def fire_values(g: Grid, C: np.ndarray, f: Firing) -> tuple:
    """``(varpi, f)``: the memberships of every input at ``f.z`` and the guarded firing
    strengths (12) in ``f``, and ``varpi`` (plus eps), which :func:`membership_gradient`
    needs."""
    z, N, span, mu, fw, tidx = f.z, f.basis, f.span, f.mu, f.w, g.term_index
    m = z.size
    h = fw.size
    prod = 1.0
    for j in range(m):
        s, row = basis_values(z[j], g.knots[j], g.points, g.order, N[j])
        for l in range(g.order):    # in place already under numba; JAX's row is new
            N = xp.put(N, (j, l), row[l])
        span = xp.put(span, j, s)
        total, row = membership_values(C[j], N[j], s, g.order, g.terms[j], mu[j])
        for t in range(g.terms[j]):
            mu = xp.put(mu, (j, t), row[t])
        prod = total if j == 0 else prod * total
    varpi = prod + g.eps
    floor = g.eps / h
    for i in range(h):
        w = mu[0, tidx[i, 0]]
        for j in range(1, m):
            w = w * mu[j, tidx[i, j]]
        fw = xp.put(fw, i, (w + floor) / varpi)
    return varpi, Firing(z, N, span, mu, f.dmu, fw, f.y)


@njit(**JIT)
def fire(g: Grid, C: np.ndarray, f: Firing) -> float:
    """The ``varpi`` of :func:`fire_values`, the firing written into ``f``."""
    return fire_values(g, C, f)[0]


@array_law
def weighted_output(w: np.ndarray, y: np.ndarray) -> float:
    """``y = sum_i w^i y^i``: the rule base's output for per-rule outputs ``y``."""
    acc = 0.0
    for i in range(w.size):
        acc += w[i] * y[i]
    return acc


@array_law
def membership_gradient(g: Grid, f: Firing, varpi: float) -> Firing:
    """``dy/dmu`` (11) of ``y = sum_i w^i y^i`` (``y^i`` in ``f.y``) into ``f.dmu``;
    returns ``f``."""
    mu, dmu, yr, tidx = f.mu, f.dmu, f.y, g.term_index
    m = f.z.size
    y = weighted_output(f.w, yr)
    for j in range(m):
        for t in range(dmu.shape[1]):
            dmu = xp.put(dmu, (j, t), 0.0)
    for i in range(yr.size):
        D = (yr[i] - y) / varpi
        for j in range(m):
            d = D
            for k in range(m):
                if k != j:
                    d = d * mu[k, tidx[i, k]]
            dmu = xp.add(dmu, (j, tidx[i, j]), d)
    return Firing(f.z, f.basis, f.span, mu, dmu, f.w, yr)


@array_law
def move_control_points(g: Grid, C: np.ndarray, f: Firing, rate: float,
                        dt: float) -> np.ndarray:
    """Forward Euler of ``dc/dt = rate dy/dc``, ``dy/dc_{s,l} = dy/dmu_s N_l`` where
    unsaturated; returns ``(C,)`` (numba, without its runtime, returns an array only
    inside a tuple).

    Only the ``d`` control points under the input's span move; then the optional shape
    projection.
    """
    N, span, mu, dmu, terms = f.basis, f.span, f.mu, f.dmu, g.terms
    d = g.order
    for j in range(span.size):
        base = span[j] - d + 1
        for t in range(terms[j]):
            gs = dmu[j, t] * xp.where(unsaturated(mu[j, t]), 1.0, 0.0)
            for l in range(d):
                C = xp.add(C, (j, t, base + l), dt * (rate * (gs * N[j, l])))
    if g.shape_projection:
        C, = project_shapes(g, C)
    return (C,)


@array_law
def project_shapes(g: Grid, C: np.ndarray) -> np.ndarray:
    """Every set unimodal with its peak in its own window (so an input's sets stay
    ordered); returns ``(C,)``."""
    for j in range(g.terms.size):
        for t in range(g.terms[j]):
            row, = project_unimodal(C[j, t, : g.points], g.peak_windows[j, t, 0],
                                   g.peak_windows[j, t, 1])
            for l in range(g.points):
                C = xp.put(C, (j, t, l), row[l])
    return (C,)


def curves(g: Grid, C: np.ndarray, j: int, grid_z: np.ndarray) -> np.ndarray:
    """Membership curves of input j on ``grid_z``: shape (T_j, len(grid_z))."""
    T = int(g.terms[j])
    out = np.empty((T, grid_z.size))
    membership_curves(C[j], g.knots[j], g.points, g.order, T, grid_z, out)
    return out
