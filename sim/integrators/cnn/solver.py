"""``cnn``: the augmented second-order cellular neural network of Zhang §4.2.1/§4.3 (eqs. 4.31–4.35).

Each scalar component of each node is a cell: the *state* ``s`` is its velocity, the *output* its
position, the input the external force. Templates: ``A = M^-1 K`` acting on displacement (as a
restoring force), ``C = M^-1 D`` on the state, ``B = M^-1`` on the input (4.32); the output follows
``dx/dt = f(s)`` with the saturation ``f(s) = (|s + K| - |s - K|) / 2`` (4.33): no cell moves faster
than K [m/s]. Kinematic cells are fixed-state, fixed-output cells (4.34).

The thesis writes no discrete update; we integrate 4.32–4.33 by forward Euler (docs/integrators-zhang.md):

- ``saturation = "state"`` (default): ``x_{n+1} = x_n + h s_n``, ``s_{n+1} = clamp(s_n + h a(x_n, s_n), -K, K)``;
- ``saturation = "output"`` (4.33 read literally): ``x_{n+1} = x_n + h clamp(s_n, -K, K)``,
  ``s_{n+1} = s_n + h a(x_n, s_n)`` (the state itself is not bounded).

With K = infinity both reduce to ``sim.integrators.explicit``. At large h the saturation keeps the motion bounded
where forward Euler diverges, but the motion settles into a bounded oscillation of amplitude about
K h rather than decaying (measured on the mass–spring–damper: error floor 0.14/0.11/0.055 m for
K = 5/4/2 with state saturation, 0.23/0.19/0.12 m with output saturation, at h = 0.01 s).
Parameters: :class:`sim.integrators.cnn.settings.CNNSettings` (the table of its module docstring);
``iterations`` is ignored (the CNN has no inner iterations).

``force_model = "energy"`` (Zhang 4.4–4.30, ``sim.integrators.cnn.energy``): the contact forces (the model's constant
nodal forces) become a Poisson energy source whose three-layer potential evolves with the simulation time
on its own CNN array, and the load is applied as the forces of that potential (4.30, signed) instead of
at the contact nodes; the restoring term ``K P`` of 4.31 is the linear FEM stiffness on displacement.
Gravity still acts as a body force. Extra settings ``energy_rho``, ``energy_gradient``.
"""
from __future__ import annotations

import numpy as np

from sim.forces import Accelerations
from sim.integrators.cnn.energy import EnergyPropagation
from sim.integrators.cnn.settings import CNNSettings
from sim.model import Model, State

def saturate(v, K: float):
    """Zhang eq. 4.33: f(v) = (|v + K| - |v - K|) / 2, i.e. v clamped to [-K, K]. Evaluated as the clamp:
    identical in exact arithmetic, free of the |.| form's rounding, and K = inf gives f(v) = v
    (the |.| form gives inf - inf = NaN)."""
    return np.clip(v, -K, K)


class CNN:
    name = "cnn"

    def __init__(self, model: Model, settings: CNNSettings | dict | None = None):
        settings = CNNSettings.of(settings)
        self.settings = settings
        self.model = model
        self.substeps = settings.substeps
        self.K = settings.K
        self.saturation = settings.saturation
        self.energy = None
        if settings.force_model == "energy":
            self.energy = EnergyPropagation(model, settings)
            settings = settings.model_copy(update={"force_model": "linear_fem"})
            inv_m = model.inverse_mass()
            self._contact_accel = np.zeros_like(model.X)
            self._contact_accel[self.energy.contact] = self.energy.contact_force
            self._contact_accel *= inv_m[:, None]
            self._inv_m = inv_m
        self.accel = Accelerations(model, settings, "cnn")
        self.kinematic = model.kinematic_mask()

    def _accelerations(self, x: np.ndarray, s: np.ndarray, phi: np.ndarray | None) -> np.ndarray:
        a = self.accel(x, s)
        if self.energy is not None:  # the contact load, redistributed by energy propagation
            a += self.energy.forces(phi, x) * self._inv_m[:, None] - self._contact_accel
        return a

    def step(self, state: State, dt: float) -> State:
        h = dt / self.substeps
        self.accel.start(state.x)
        x, t = state.x.copy(), state.t
        s = state.private.get("cnn_state", state.v).copy()  # the (unsaturated) cell state
        phi = None
        if self.energy is not None:
            phi = state.private.get("cnn_potential", np.zeros_like(x)).copy()
        for _ in range(self.substeps):
            a = self._accelerations(x, s, phi)
            if phi is not None:
                phi = self.energy.evolve(phi, h)
            x_old = x
            if self.saturation == "state":
                x = x + h * s
                s = saturate(s + h * a, self.K)
            else:
                x = x + h * saturate(s, self.K)
                s = s + h * a
            t += h
            self.accel.set_kinematic(x, s, t, h)
            s[self.kinematic] = (x[self.kinematic] - x_old[self.kinematic]) / h  # the target's speed
            self.accel.check(x, t, h)
        private = dict(state.private)
        private["cnn_state"] = s
        if phi is not None:
            private["cnn_potential"] = phi
        v = saturate(s, self.K)  # the velocity the output actually moves with
        return State(x=x, v=v, t=t, private=private)
