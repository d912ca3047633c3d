"""``explicit``: plain forward Euler, the baseline Zhang compares against (§4.3.2).

``x_{n+1} = x_n + h v_n``, ``v_{n+1} = v_n + h a(x_n, v_n)`` (the position advances with the *old*
velocity; symplectic Euler would be stable where this one is not). Stable only for h below about
the explicit critical step ``l_min / c`` (Zhang eq. 5.12); beyond it, it diverges, and the integrator
raises :class:`SimulationDiverged` instead of returning NaN.

| name | default | unit | range | equation |
|---|---|---|---|---|
| ``substeps`` | 1 | – | >= 1 | h = dt / substeps |
| ``iterations`` | 1 | – | >= 1 | ignored (forward Euler has no inner iterations) |
| ``force_model`` | "constitutive" | – | "constitutive", "linear_fem" | f_int (``sim.forces``) |
| ``rayleigh_alpha`` | 0 | 1/s | [0, 1e3] | D = alpha M + beta K |
| ``rayleigh_beta`` | 0 | s | [0, 1] | D = alpha M + beta K |
| ``kernel`` | "numba" | – | "numba", "numpy" | constitutive forces |

``ExplicitSceneSettings`` is the scene's ``[simulation.explicit]`` table; ``ExplicitSettings`` adds ``substeps`` and
``iterations`` (set from ``[simulation]``) and the kernel.
"""
from __future__ import annotations

from pydantic import Field

from sim.forces import Accelerations, ForceKernel, ForceSettings
from sim.model import Model, State


class ExplicitSceneSettings(ForceSettings):
    """The scene's ``[simulation.explicit]`` table."""


class ExplicitSettings(ExplicitSceneSettings, ForceKernel):
    """Every parameter of the ``explicit`` integrator (the table in the module docstring)."""

    substeps: int = Field(1, ge=1, le=1000, description="substeps per step [-]")
    iterations: int = Field(1, ge=1, le=10000, description="ignored: forward Euler has no inner iterations")


class ExplicitEuler:
    name = "explicit"

    def __init__(self, model: Model, settings: ExplicitSettings | dict | None = None):
        settings = ExplicitSettings.of(settings)
        self.settings = settings
        self.model = model
        self.substeps = settings.substeps
        self.accel = Accelerations(model, settings, "explicit")
        self.kinematic = model.kinematic_mask()

    def step(self, state: State, dt: float) -> State:
        h = dt / self.substeps
        self.accel.start(state.x)
        x, v, t = state.x.copy(), state.v.copy(), state.t
        for _ in range(self.substeps):
            a = self.accel(x, v)
            x_old = x
            x = x + h * v
            v = v + h * a
            t += h
            self.accel.set_kinematic(x, v, t, h)
            v[self.kinematic] = (x[self.kinematic] - x_old[self.kinematic]) / h  # the target's speed
            self.accel.check(x, t, h)
        return State(x=x, v=v, t=t, private=state.private)
