"""The large-deflection cantilever of issue 17 (discretisation error): a 2 x 0.2 x 0.2 m beam along x, E = 1 MPa,
nu = 0.3, rho = 1000 kg/m^3, the face x = 0 fixed (every node on it, corner and edge nodes alike), gravity -z;
Neo-Hookean (Zhang eq. 5.35, whose small-strain limit is linear elasticity with the model's E and nu).

Mesh level k: ``procedural.beam`` with ``(10 2^k, 2^k, 2^k)`` hex cells (``BASE_CELLS`` times 2^k), 6 tets each:
60 x 8^k tets (level 3: 30,720, the issue's figure); each level halves the element size of the one before. Linear (4-node) or quadratic
(10-node, ``sim.integrators.reference_quadratic``) tets on it, solved by the quasi-static Newton reference with the
gravity ramped in ``load_steps`` equal increments (full gravity bends the beam far past small deflection: the
linear Euler–Bernoulli tip deflection ``q L^4 / (8 EI)`` would be 5.9 m on a 2 m beam).

The tip deflection is ``-mean u_z`` over the nodes of the end face x = L (the grid is symmetric about the beam's
axis, so this is the face centre's for a rigidly rotating face).

Small load (``gravity_scale`` << 1), the beam theories: Euler–Bernoulli ``q L^4 / (8 E I)`` plus Timoshenko's
shear deflection ``q L^2 / (2 k G A)`` with Cowper's ``k = 10 (1 + nu) / (12 + 11 nu)`` for a rectangle
(:func:`beam_theory_tip_deflection`).
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from sim.errors import SimulationDiverged
from sim.integrators.reference_quadratic import quadratic_model, reference_for
from sim.mesh import procedural, select
from sim.model import Model

LENGTH, SIDE = 2.0, 0.2  # [m]
E, NU, DENSITY, GRAVITY = 1.0e6, 0.3, 1000.0, 9.81  # [Pa], [-], [kg/m^3], [m/s^2]


BASE_CELLS = (10, 1, 1)  # level 0: 60 tets; the test suite starts from (3, 1, 1), cheaper


def level_cells(level: int, base=BASE_CELLS) -> tuple[int, int, int]:
    return tuple(int(c) * 2**level for c in base)


def level_tets(level: float, base=BASE_CELLS) -> float:
    """Tets at ``level`` (fractional levels: the count a level between two would have)."""
    count = 6.0 * float(np.prod(base)) * 8.0**level
    return int(count) if float(level).is_integer() else count


def cantilever_model(level: int, quadratic: bool, nu: float = NU, gravity_scale: float = 1.0,
                     base=BASE_CELLS) -> Model:
    """The beam at mesh ``level`` on linear or quadratic tets, its face x = 0 fixed."""
    mesh = procedural.beam((LENGTH, SIDE, SIDE), level_cells(level, base))
    material = {"E": E, "nu": nu, "density": DENSITY, "constitutive": "neo_hookean",
                "gravity": np.array([0.0, 0.0, -GRAVITY * gravity_scale])}
    model = quadratic_model(mesh, **material) if quadratic else Model.from_mesh(mesh, **material)
    model.fixed[select.nodes_on_side(model.X, 0, "min")] = True
    return model


@dataclass
class CantileverSolution:
    level: int
    quadratic: bool
    anp: bool
    nodes: int
    tets: int
    tip_deflection: float  # [m], downwards positive
    tip_axial: float  # [m] mean u_x of the end face (negative: the tip pulls back as the beam bends)
    newton_iterations: int
    wall_s: float

    def as_dict(self) -> dict:
        return dict(self.__dict__)


def solve_cantilever(level: int, quadratic: bool, load_steps: int = 8, nu: float = NU, gravity_scale: float = 1.0,
                     anp: bool = False, tol: float = 1e-8, base=BASE_CELLS) -> CantileverSolution:
    """Quasi-static equilibrium under gravity, ramped in ``load_steps`` increments; an increment whose Newton solve
    fails is halved (down to 1/16 of the initial one)."""
    start = time.perf_counter()
    model = cantilever_model(level, quadratic, nu, gravity_scale, base)
    settings = {"mode": "quasistatic", "tol": tol, "anp": anp}
    solver = reference_for(model, settings)
    g_full = model.gravity.copy()
    x = model.X.copy()
    previous = None  # (load fraction, positions) of the equilibrium before x
    full = 1.0 / load_steps
    inc, s, iterations = full, 0.0, 0
    while s < 1.0 - 1e-12:
        s_next = min(s + inc, 1.0)
        model.gravity = g_full * s_next
        # start from the secant predictor along the load path (the last two equilibria extrapolated to s_next):
        # it saves about half the Newton iterations of starting from the last equilibrium
        start_x = x if previous is None else x + (x - previous[1]) * (s_next - s) / (s - previous[0])
        try:
            x_next = solver.solve(start_x, None, 1.0, 0.0)
        except SimulationDiverged:
            if inc <= full / 16:
                raise
            inc *= 0.5
            continue
        iterations += solver.last_iterations
        previous = (s, x)
        x, s = x_next, s_next
        inc = min(2.0 * inc, full)
    tip = select.nodes_on_side(model.X, 0, "max")
    u = x[tip] - model.X[tip]
    return CantileverSolution(level, quadratic, anp, int(model.n_nodes), int(model.n_tets), -float(u[:, 2].mean()),
                              float(u[:, 0].mean()), iterations, time.perf_counter() - start)


def small_load_tip_deflection(level: int, quadratic: bool, nu: float = NU, base=BASE_CELLS) -> float:
    """The small-deflection limit [m] per unit gravity scale: one linear solve ``K u = f`` with the tangent stiffness
    at rest (linear elasticity for every law), the same element and boundary conditions as :func:`solve_cantilever`."""
    model = cantilever_model(level, quadratic, nu, 1.0, base)
    solver = reference_for(model, {"mode": "quasistatic"})
    free = ~np.repeat(model.kinematic_mask(), 3)
    K = solver._hessian(model.X, 1.0, project=False).tocsr()[free][:, free]
    u = np.zeros(3 * model.n_nodes)
    u[free] = solver._newton_step(K, -model.nodal_external_force().ravel()[free])  # K u = f
    tip = select.nodes_on_side(model.X, 0, "max")
    return -float(u.reshape(-1, 3)[tip, 2].mean())


def beam_theory_tip_deflection(gravity_scale: float = 1.0, nu: float = NU) -> float:
    """Euler–Bernoulli plus Timoshenko shear tip deflection [m] of the uniformly loaded cantilever (small load)."""
    area = SIDE * SIDE
    inertia = SIDE**4 / 12.0
    q = DENSITY * GRAVITY * gravity_scale * area  # [N/m]
    shear_modulus = E / (2.0 * (1.0 + nu))
    k = 10.0 * (1.0 + nu) / (12.0 + 11.0 * nu)
    return q * LENGTH**4 / (8.0 * E * inertia) + q * LENGTH**2 / (2.0 * k * shear_modulus * area)


def richardson(values: list[float], assumed_order: float) -> dict:
    """Richardson extrapolation of a quantity at levels halving the element size: with three or more levels the
    observed order ``p = log2((v1 - v0) / (v2 - v1))`` of the last three (used when between 1 and 8, else the
    ``assumed_order``), with two the assumed order; ``v_inf = v_n + (v_n - v_n-1) / (2^p - 1)``."""
    v = [float(a) for a in values]
    if len(v) < 2:
        raise ValueError("richardson: needs at least two levels")
    observed = float("nan")
    if len(v) >= 3:
        d0, d1 = v[-2] - v[-3], v[-1] - v[-2]
        if d0 != 0.0 and d1 != 0.0 and d0 * d1 > 0.0:
            observed = float(np.log2(d0 / d1))
    used = observed if 1.0 <= observed <= 8.0 else assumed_order
    extrapolated = v[-1] + (v[-1] - v[-2]) / (2.0**used - 1.0)
    return {"values": v, "observed_order": observed, "order_used": used,
            "order_source": "observed" if used == observed else "assumed", "extrapolated": extrapolated,
            "error_estimate": abs(extrapolated - v[-1])}


def levels_to_reach(errors: list[float], levels: list[int], target: float, base=BASE_CELLS) -> dict:
    """The first level whose relative error is within ``target``; else the level (fractional) and element count
    extrapolated from the rate observed between the last two levels, ``e_k ~ 2^(-r k)``."""
    for level, err in zip(levels, errors):
        if err <= target:
            return {"level": level, "tets": level_tets(level, base), "how": "measured", "rate": None}
    if len(errors) < 2 or not (errors[-1] > 0.0 and errors[-2] > errors[-1]):
        return {"level": None, "tets": None, "how": "not falling: no extrapolation", "rate": None}
    rate = float(np.log2(errors[-2] / errors[-1]))
    level = levels[-1] + float(np.log2(errors[-1] / target)) / rate
    return {"level": level, "tets": level_tets(level, base), "how": "extrapolated", "rate": rate}
