"""``lqr``: linear-quadratic regulator on the plant linearised at its operating point.

The linearisation (:meth:`.plant_model.PlantModel.state_space`, numerical Jacobians of
the plant's own ``f``) is ``x' = A (x - x*) + B (u - u*)`` with ``A`` the chain of
integrators whose last row is ``a = df/dx`` and ``B = b e_n``, ``b = df/du``.  The gain
minimises ``int (e^T Q e + R v^2) dt`` on that model (Anderson and Moore, *Optimal
Control: Linear Quadratic Methods*, 1990, ch. 2-3):

    A^T P + P A - P B R^-1 B^T P + Q = 0,        K = R^-1 B^T P

(``P`` from ``scipy.linalg.solve_continuous_are``).  Tracking uses the linear model's
feedforward, so that on the linear model ``e' = (A - B K) e`` exactly:

    u = u* + (r^(n) - a^T (r - x*)) / b - K e,      r = [r .. r^(n-1)],  e = x - r.

``V = e^T P e`` is recorded: it is the cost-to-go of the linear design and a Lyapunov
function of ``A - B K``.

Defaults (:class:`LQRSettings`): ``Q = diag(10^n, .., 100, 10)`` weighs each error
derivative ten times less than the one before (``diag(100, 10)`` for n = 2); ``R = 1 /
b^2`` prices the acceleration ``b u`` the input produces rather than ``u`` itself, so
the design does not depend on the input's units (newtons on the cart-pole, where ``b ~
1/41``, or Example 2's unit gain).  On a double integrator these give closed-loop poles
``-2.7 +/- 1.4j``, about three times the references' 1 rad/s.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from tspend.errors import ScenarioError
from tspend.controllers.base import diag_width, diagnostics
from tspend.controllers.plant_model import plant_model
from tspend.controllers.settings import setting, settings_for

if TYPE_CHECKING:
    from tspend.config import Scenario


@dataclass(frozen=True)
class LQRSettings:
    """``[controllers.lqr]``."""

    #: what ``tspend tune`` searches: only Q/R matters, so R against the default Q
    SEARCH = {"R": (1e-6, 1e6, "log")}

    Q: tuple[tuple[float, ...], ...] | None = setting(
        None, "state weight on e, n x n SPD (default diag(10^n, .., 100, 10))", kind="matrix")
    R: float | None = setting(None, "input weight (default 1 / b^2, b = df/du at the "
                                    "operating point)", low=0.0, strict=True)


def default_Q(n: int) -> np.ndarray:
    return np.diag([10.0 ** (n - i) for i in range(n)])


def lqr_gain(A: np.ndarray, B: np.ndarray, Q: np.ndarray, R: float) -> tuple[np.ndarray, np.ndarray]:
    """``(K, P)``: the Riccati solution ``P`` and ``K = R^-1 B^T P`` (1 x n)."""
    from scipy.linalg import solve_continuous_are

    P = solve_continuous_are(A, B, Q, np.array([[R]]))
    return (B.T @ P) / R, P


class LQRController:
    """The ``lqr`` kind (a :class:`~tspend.controllers.base.Controller`)."""

    kind = "lqr"

    def __init__(self, A: np.ndarray, B: np.ndarray, Q: np.ndarray, R: float,
                 x_op: np.ndarray, u_op: float) -> None:
        self.A, self.B, self.Q, self.R = A, B, Q, float(R)
        self.order = A.shape[0]
        K, P = lqr_gain(A, B, Q, self.R)
        self.K, self.P = K[0], P
        self.a, self.b = A[-1].copy(), float(B[-1, 0])
        self.x_op, self.u_op = np.asarray(x_op, dtype=float), float(u_op)
        self.diagnostics = diagnostics(
            ("u_ff", 1, {"panel": "control",
                         "description": "feedforward u* + (r^(n) - a^T (r - x*)) / b"}),
            ("u_fb", 1, {"panel": "control", "description": "feedback -K e"}),
            ("V", 1, {"panel": "lyapunov", "log": True,
                      "description": "cost-to-go e^T P e of the linear design"}))
        self.diag = np.zeros(diag_width(self.diagnostics))

    def closed_loop(self) -> np.ndarray:
        """``A - B K``, Hurwitz by construction."""
        return self.A - self.B @ self.K[None, :]

    def reset(self, rng: np.random.Generator) -> None:
        """Nothing is adapted and nothing is drawn."""

    def step(self, x: np.ndarray, ref: np.ndarray, dt: float) -> float:
        n = self.order
        r = ref[:n]
        e = x - r
        u_ff = self.u_op + (ref[n] - float(self.a @ (r - self.x_op))) / self.b
        u_fb = -float(self.K @ e)
        d = self.diag
        d[0], d[1], d[2] = u_ff, u_fb, float(e @ self.P @ e)
        return u_ff + u_fb

    def parameters(self) -> dict[str, np.ndarray]:
        return {}


def build(scenario: "Scenario") -> LQRController:
    s: LQRSettings = settings_for(scenario, "lqr")
    model = plant_model(scenario)
    A, B = model.state_space()
    b = float(B[-1, 0])
    if b == 0.0:
        raise ScenarioError(f"{scenario.path}: controllers.lqr: df/du = 0 at the operating "
                            f"point of plant '{model.name}'; LQR cannot act")
    Q = np.asarray(s.Q) if s.Q is not None else default_Q(model.order)
    R = s.R if s.R is not None else 1.0 / b**2
    return LQRController(A, B, Q, R, np.asarray(model.x_op), model.u_op)
