"""Nodal accelerations for the explicit-type integrators (``explicit``, ``cnn``):
``a = M^-1 (f_int(x) - D v + f_ext)`` on free nodes, zero on kinematic ones, projected on the free motion
``P a`` on nodes held in some components only (``sim.model.PartialTargets``).

Internal forces come from the shared constitutive library (``force_model = "constitutive"``, the
model's own nonlinear material) or from the linear FEM stiffness ``f_int = -K (x - X)``
(``"linear_fem"``). Damping is Rayleigh, ``D = alpha M + beta K`` (settings ``rayleigh_alpha`` [1/s]
and ``rayleigh_beta`` [s]). The constitutive forces run in the per-tet numba kernel of
``sim.constitutive.force_kernels`` (``kernel = "numba"``, default) for StVK and the (stable / anisotropic)
Neo-Hookean models with element pressure; ``kernel = "numpy"``, Valanis–Landel curves and average nodal pressure
use ``sim.constitutive.elastic`` (the reference the kernel is tested against). From
``force_kernels.PARALLEL_MIN_TETS`` tets with
more than one numba thread, the kernel's two-thread version (per-tet contributions, then a per-node gather in tet
order: bit-identical forces for any thread count).
"""
from __future__ import annotations

from typing import Literal

import numba
import numpy as np
from pydantic import Field

from sim.constitutive import elastic, force_kernels, linear_fem, models
from sim.constitutive.kernels import MATERIALS
from sim.errors import SimulationDiverged
from sim.settings import Settings

FORCE_MODELS = ("constitutive", "linear_fem")
KERNELS = ("numba", "numpy")


class ForceSettings(Settings):
    """The force-model keys of the explicit-type integrators' scene tables (``explicit``, ``cnn``)."""

    force_model: Literal[FORCE_MODELS] = Field(  # type: ignore[valid-type]
        "constitutive", description="the model's own material, or the linear FEM stiffness on displacement")
    rayleigh_alpha: float = Field(0.0, ge=0.0, le=1e3, description="mass-proportional damping alpha [1/s]")
    rayleigh_beta: float = Field(0.0, ge=0.0, le=1.0, description="stiffness-proportional damping beta [s]")


class ForceKernel(Settings):
    """The kernel of the constitutive forces (code and benchmarks choose it; scenes do not)."""

    kernel: Literal[KERNELS] = Field(  # type: ignore[valid-type]
        "numba", description="the per-tet numba kernel, or the NumPy reference (sim.constitutive.elastic)")


class AccelerationSettings(ForceSettings, ForceKernel):
    """What :class:`Accelerations` reads."""


class Accelerations:
    """``settings``: the integrator's settings (any model with the fields of :class:`AccelerationSettings`, or a
    mapping of them); ``force_model`` "energy" (cnn) is turned into "linear_fem" by the caller."""

    def __init__(self, model, settings, who: str):
        if not isinstance(settings, Settings):
            settings = AccelerationSettings.of(settings)
        self.model = model
        self.who = who
        self.force_model = settings.force_model
        kernel = settings.kernel
        self._kernel_args = None
        if (kernel == "numba" and self.force_model == "constitutive" and not models.uses_anp(model)
                and model.constitutive in MATERIALS):
            name, mu, lam, eta, a0 = models.model_params(model)
            m = model.n_tets
            self._kernel_args = (
                np.ascontiguousarray(model.tets, dtype=np.int64), np.ascontiguousarray(model.Dm_inv, dtype=np.float64),
                np.ascontiguousarray(model.volume, dtype=np.float64), np.ascontiguousarray(mu, dtype=np.float64),
                np.ascontiguousarray(lam, dtype=np.float64),
                np.ascontiguousarray(np.zeros(m) if eta is None else eta, dtype=np.float64),
                np.ascontiguousarray(np.zeros((m, 3)) if a0 is None else a0, dtype=np.float64),
                MATERIALS[name], False, 1.0, np.zeros((1, 3, 3)), np.zeros(1))
        # two threads on large meshes (bit-identical forces; sim.constitutive.force_kernels.forces_and_energy_parallel)
        self._large = model.n_tets >= force_kernels.PARALLEL_MIN_TETS
        self._parallel_scratch = None
        self.alpha = float(settings.rayleigh_alpha)
        self.beta = float(settings.rayleigh_beta)
        need_K = self.force_model == "linear_fem" or self.beta != 0.0
        self.K = linear_fem.stiffness_matrix(model) if need_K else None
        self.inv_mass = np.where(model.mass > 0, 1.0 / np.maximum(model.mass, 1e-300), 0.0)
        self._kinematic_targets = model.kinematic()
        self.kinematic = self._kinematic_targets.nodes
        self.partial = model.partial()  # nodes held in some components: accelerations projected on their free motion
        self.f_ext = model.nodal_external_force()
        extent = np.ptp(model.X, axis=0)
        self.blow_up = 100.0 * float(np.linalg.norm(extent)) + 1.0  # displacement that means divergence [m]
        self._tets = np.ascontiguousarray(model.tets, dtype=np.int64)
        self.inverted_at_start = None  # elements inverted in the first state stepped from (they may recover)
        edges = model.X[model.tets[:, [1, 2, 3, 2, 3, 3]]] - model.X[model.tets[:, [0, 0, 0, 1, 1, 2]]]
        wave_speed = np.sqrt((model.lam + 2.0 * model.mu) / model.density)  # dilatational, per tet
        self.critical_step = float((np.linalg.norm(edges, axis=2).min(axis=1) / wave_speed).min())  # Zhang 5.12

    def __call__(self, x: np.ndarray, v: np.ndarray) -> np.ndarray:
        if self._kernel_args is not None:
            f = np.empty((x.shape[0], 3))
            x = np.ascontiguousarray(x, dtype=np.float64)
            threads = self._threads()
            if threads > 1:
                force_kernels.forces_and_energy_parallel(x, f, *self._kernel_args, *self._scratch(), threads)
            else:
                force_kernels.forces_and_energy(x, f, *self._kernel_args)
        elif self.force_model == "constitutive":
            f = elastic.elastic_forces(self.model, x)
        else:
            f = -(self.K @ (x - self.model.X).ravel()).reshape(x.shape)
        f = f + self.f_ext - self.alpha * self.model.mass[:, None] * v
        if self.beta != 0.0:
            f = f - self.beta * (self.K @ v.ravel()).reshape(v.shape)
        a = f * self.inv_mass[:, None]
        a[self.kinematic] = 0.0
        self.partial.project(a)
        return a

    def _threads(self) -> int:
        return numba.get_num_threads() if self._large else 1

    def _scratch(self):
        """Incidence lists and per-tet scratch of the two-thread force kernel (built on first use)."""
        if self._parallel_scratch is None:
            m = self.model.n_tets
            start, corner = force_kernels.node_incidences(self._tets, self.model.n_nodes)
            self._parallel_scratch = (start, corner, np.empty((4 * m, 3)), np.empty(m), np.empty(m))
        return self._parallel_scratch

    def _count_inverted(self, x: np.ndarray) -> int:
        x = np.ascontiguousarray(x, dtype=np.float64)
        if self._threads() > 1:
            return int(force_kernels.count_inverted_parallel(x, self._tets))
        return int(force_kernels.count_inverted(x, self._tets))

    def start(self, x: np.ndarray) -> None:
        """Note how many elements are inverted in the first state the integrator steps from."""
        if self.inverted_at_start is None:
            self.inverted_at_start = self._count_inverted(x)

    def check(self, x: np.ndarray, t: float, h: float | None = None) -> None:
        """Raise SimulationDiverged for non-finite or runaway positions (never return NaN frames), and when
        (constitutive force model) elements invert that were not inverted at the start: with a step above
        the explicit critical step the CNN's saturation keeps the motion bounded, but elements folding
        through themselves are outside what the nonlinear material describes (Zhang 5.35 is undefined for
        J <= 0)."""
        if not np.isfinite(x).all():
            raise SimulationDiverged(f"{self.who}: non-finite positions at t = {t:.6g} s; reduce dt")
        worst = float(np.abs(x - self.model.X).max())
        if worst > self.blow_up:
            raise SimulationDiverged(f"{self.who}: displacement {worst:.3g} m at t = {t:.6g} s exceeds 100x the "
                                     f"body's size: the integration diverged; reduce dt")
        if self.force_model != "constitutive":
            return  # linear FEM forces are linear in x: an inverted element is only a large displacement there
        inverted = self._count_inverted(x)
        if inverted > (self.inverted_at_start or 0):
            step = "" if h is None else f"the step {h:.3g} s against "
            raise SimulationDiverged(
                f"{self.who}: the integration diverged: {inverted} elements inverted at t = {t:.6g} s "
                f"({self.inverted_at_start or 0} at the start); compare {step}the explicit critical step "
                f"{self.critical_step:.3g} s (Zhang 5.12) and reduce dt or add substeps")

    def set_kinematic(self, x: np.ndarray, v: np.ndarray, t: float, h: float) -> None:
        """Place fixed and prescribed nodes at their targets at ``t``, moving with their targets' speed
        over the last step (not the gap to where the integrator's update had put them)."""
        idx = self.kinematic
        target = self._kinematic_targets.at(t)
        v[idx] = (target - self._kinematic_targets.at(t - h)) / h
        x[idx] = target
        self.partial.place(x, t)  # held components on their targets, free ones where the update put them
        self.partial.velocity(v, t, h)
