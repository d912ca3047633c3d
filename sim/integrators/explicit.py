"""``explicit``: plain forward Euler, the baseline Zhang compares against (§4.3.2).

``x_{n+1} = x_n + h v_n``, ``v_{n+1} = v_n + h a(x_n, v_n)`` (the position advances with the *old*
velocity; symplectic Euler would be stable where this one is not). Stable only for h below about
the explicit critical step ``l_min / c`` (Zhang eq. 5.12); beyond it, it diverges, and the integrator
raises :class:`SimulationDiverged` instead of returning NaN.
Settings: ``substeps``, ``force_model``, ``rayleigh_alpha``, ``rayleigh_beta`` (see ``sim.forces``);
``iterations`` is ignored (forward Euler has no inner iterations).
"""
from __future__ import annotations

from sim.forces import Accelerations
from sim.model import Model, State


class ExplicitEuler:
    name = "explicit"

    def __init__(self, model: Model, settings: dict):
        self.model = model
        self.substeps = int(settings.get("substeps", 1))
        if self.substeps < 1:
            raise ValueError(f"explicit: substeps must be a positive integer, found {self.substeps}")
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
