"""The 1-DOF mass–spring–damper of Zhang §4.3.2.1, its analytic solution, and the explicit and CNN
updates on it (the same discrete schemes as ``sim.integrators.explicit`` and ``sim.integrators.cnn``, in scalar form).

A weight of mass m hangs at y = -1 m from the origin on a spring (stiffness k, rest length l0 = 1 m)
and a damper d; it starts at rest length with velocity v0 = -5 m/s (no gravity):
``m y'' = -k (y - y_rest) - d y'`` with ``y_rest = -l0``.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim.integrators.cnn.solver import saturate


@dataclass(frozen=True)
class MassSpringDamper:
    m: float = 0.2
    k: float = 400.0
    d: float = 2.0
    l0: float = 1.0
    y0: float = -1.0
    v0: float = -5.0

    @property
    def y_rest(self) -> float:
        return -self.l0

    def analytic(self, t: np.ndarray) -> np.ndarray:
        """Closed-form y(t) (underdamped: d^2 < 4 k m)."""
        t = np.asarray(t, dtype=np.float64)
        gamma = self.d / (2.0 * self.m)
        omega_d = np.sqrt(self.k / self.m - gamma**2)
        u0 = self.y0 - self.y_rest
        a = u0
        b = (self.v0 + gamma * u0) / omega_d
        return self.y_rest + np.exp(-gamma * t) * (a * np.cos(omega_d * t) + b * np.sin(omega_d * t))

    def acceleration(self, y: float, v: float) -> float:
        return (-self.k * (y - self.y_rest) - self.d * v) / self.m


def simulate(system: MassSpringDamper, dt: float, t_end: float, scheme: str = "explicit", K: float = np.inf,
             saturation: str = "state") -> tuple[np.ndarray, np.ndarray]:
    """Times and positions of one scheme: ``explicit`` (forward Euler: the position advances with the
    old velocity) or ``cnn`` (the augmented CNN, Zhang 4.32–4.33, by forward Euler; see sim.integrators.cnn)."""
    n = int(round(t_end / dt))
    ys = np.empty(n + 1)
    y, s = system.y0, system.v0
    ys[0] = y
    with np.errstate(over="ignore", invalid="ignore"):
        for i in range(n):
            a = system.acceleration(y, s)
            if scheme == "explicit":
                y, s = y + dt * s, s + dt * a
            elif scheme == "cnn":
                if saturation == "state":
                    y, s = y + dt * s, float(saturate(s + dt * a, K))
                else:  # output: only the position update sees the clamped velocity
                    y, s = y + dt * float(saturate(s, K)), s + dt * a
            else:
                raise ValueError(f"unknown scheme {scheme!r}; expected explicit or cnn")
            ys[i + 1] = y
    return np.arange(n + 1) * dt, ys
