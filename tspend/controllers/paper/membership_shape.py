"""Whether adapted membership functions still read as fuzzy sets (issue 15, interpretability).

The second type law moves the B-spline control points freely, so a set may grow a second
hump, collapse, or overtake its neighbour (Example 2's x_o2 sets after 20 s: NS with two
humps, Z reduced to two small bumps).  :func:`membership_shape` measures, on a fine grid
of each input's interval, for every set of every input:

* ``humps``: the number of local maxima of the curve, counted with a hysteresis ``tol``
  (ripples smaller than that are ignored; the curve is taken as 0 beyond the interval,
  so a shoulder set peaking at an end counts one hump); ``unimodal`` is ``humps == 1``;
* ``peak``: where the curve is highest (the centre of its top plateau) and ``height``;

and per input whether the sets are ``ordered``: their peaks do not decrease from the
first term to the last (sets that vanished are left out).  The summary ``score`` is the
fraction of sets that are unimodal and sit in order (1.0 for the initial sets).  The
optional ``shape_projection = "unimodal"`` of the scenario keeps the score at 1.
"""

from __future__ import annotations

import numpy as np


def humps(mu: np.ndarray, tol: float = 1e-3) -> int:
    """Local maxima of the curve ``mu`` (zero outside it), ignoring ripples below ``tol``."""
    count, rising, extreme = 0, True, 0.0
    for v in np.append(mu, 0.0):
        if rising:
            if v > extreme:
                extreme = v
            elif v < extreme - tol:
                count, rising, extreme = count + 1, False, v
        elif v < extreme:
            extreme = v
        elif v > extreme + tol:
            rising, extreme = True, v
    return count


def set_shape(z: np.ndarray, mu: np.ndarray, tol: float = 1e-3) -> dict:
    """Humps, unimodality, peak position and height of one set's curve ``mu`` on ``z``."""
    height = float(mu.max())
    top = z[mu >= height - tol]
    k = humps(mu, tol)
    return {"humps": k, "unimodal": k == 1, "peak": float(0.5 * (top[0] + top[-1])),
            "height": height}


def membership_shape(controller, points: int = 401, tol: float = 1e-3) -> dict:
    """The shape of every fuzzy set of a paper controller (after a run, or at any time).

    Returns ``{"inputs": {"model/x_o1": {"ordered": bool, "sets": {"NB": {...}, ..}}, ..},
    "unimodal": fraction of sets unimodal, "ordered": fraction of inputs ordered,
    "score": fraction of sets unimodal and in order}``.
    """
    inputs, n_sets, n_unimodal, n_good = {}, 0, 0, 0
    for group, group_inputs in controller.inputs.items():
        for j, inp in enumerate(group_inputs):
            z, curves = controller.curves(group, j, points)
            sets = {name: set_shape(z, mu, tol) for name, mu in zip(inp.term_names, curves)}
            shapes = list(sets.values())
            alive = [s for s in shapes if s["height"] > tol]
            peaks = np.array([s["peak"] for s in alive])
            ordered = bool(np.all(np.diff(peaks) >= 0.0))
            for t, s in enumerate(shapes):
                # in order: its peak lies between its living neighbours' peaks
                left = [o["peak"] for o in shapes[:t] if o["height"] > tol]
                right = [o["peak"] for o in shapes[t + 1:] if o["height"] > tol]
                s["in_order"] = (s["height"] > tol and (not left or left[-1] <= s["peak"])
                                 and (not right or s["peak"] <= right[0]))
                n_sets += 1
                n_unimodal += s["unimodal"]
                n_good += s["unimodal"] and s["in_order"]
            inputs[f"{group}/{inp.name}"] = {"ordered": ordered, "sets": sets}
    return {"inputs": inputs, "unimodal": n_unimodal / n_sets,
            "ordered": float(np.mean([v["ordered"] for v in inputs.values()])),
            "score": n_good / n_sets}
