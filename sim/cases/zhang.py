"""The quantitative cases of Zhang §5.3.2 (and the measurement lines of docs/design.md, "Zhang §5.3: cases, locking and measurement lines"), shared by the
accuracy tests and the accuracy benchmark.

- **Cylinder**: length 2 m along z, radius 0.5 m, left face (z = 0) fixed, every component of the
  right face (z = 2) prescribed, moved 0.4 m along the axis (``+0.4`` extension, ``-0.4``
  compression). Measured: u on the line where the XZ plane meets the surface (y = 0, x = +r).
  With ``slide=True`` the right face is only moved axially and may slide sideways: compressed by
  0.4 m this buckles at about 0.31 m (a hard case).
- **Cube shear**: 2 m cube, the thesis's y axis vertical: bottom (y = 0) fixed, top (y = 2) moved
  +0.5 m in z. Measured: u_z on the line x = 2 m, y = 1 m (mid-height of the right face, along z).
- **Cube stretch** (Zhang §5.3.3, Fig. 5.8(a), the isotropic extension; issue 17's cube "under stretch"): the same
  cube, bottom fixed, top moved +0.3 m along its normal (y here; a 15 % stretch with clamped ends). Measured: u_x, the sideways
  contraction, on the line x = 2 m, z = 1 m (the right face's vertical mid-line, along y): zero at the clamped
  ends, largest near mid-height, where the near-incompressible cube (nu = 0.49) narrows most.

Material: E = 3000 Pa, nu = 0.49, rho = 1000 kg/m^3, the Neo-Hookean form of Zhang eq. 5.35 unless
another constitutive model is asked for.

Mesh levels (the report's mesh-converged references, ``tissuerender.report.zhang_mesh``): ``level`` k refines the
case's mesh k times (1 tet -> 8, ``sim.mesh.refine``) and ``quadratic`` puts 10-node tets on it
(``sim.integrators.reference_quadratic``). Both keep the case mesh's nodes first with their indices, so ``x[:n]`` of
any level is at the case mesh's nodes; edges stay straight, so every level meshes the case mesh's polyhedron (the
cylinder's facets are not refined towards the round surface). The boundary conditions hold every node on the faces
(edge midpoints included); ``line`` lists the level's own nodes on the measurement line.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sim.constitutive import elastic
from sim.integrators.reference_quadratic import quadratic_model
from sim.mesh import procedural, select
from sim.mesh.refine import refine
from sim.mesh.types import TetMesh
from sim.model import Model, PrescribedDisplacement


@dataclass
class Case:
    name: str
    model: Model
    line: np.ndarray  # node ids on the measurement line, sorted along it
    line_coord: np.ndarray  # their coordinate along the line [m]
    ramp_time: float  # the prescribed motion ramps over [0, ramp_time] s
    component: int = 0  # the displacement component the thesis plots along the line (Figs. 5.5(c)-5.7(c))


def _line_nodes(points, fixed_axes: dict[int, float], along: int, tol: float):
    mask = np.ones(points.shape[0], dtype=bool)
    for axis, value in fixed_axes.items():
        mask &= np.abs(points[:, axis] - value) <= tol
    idx = np.flatnonzero(mask)
    order = np.argsort(points[idx, along])
    return idx[order], points[idx[order], along]


def _level_model(mesh: TetMesh, level: int, quadratic: bool, **material) -> Model:
    """The model on ``mesh`` refined ``level`` times, on linear or quadratic tets (module docstring)."""
    for _ in range(level):
        mesh = refine(mesh)
    return quadratic_model(mesh, **material) if quadratic else Model.from_mesh(mesh, **material)


def zhang_cylinder(h: float = 0.125, displacement: float = 0.4, constitutive: str = "neo_hookean",
                   E: float = 3000.0, nu: float = 0.49, density: float = 1000.0, slide: bool = False,
                   ramp_time: float = 1.0, level: int = 0, quadratic: bool = False) -> Case:
    mesh = procedural.cylinder(2.0, 0.5, h)
    model = _level_model(mesh, level, quadratic, E=E, nu=nu, density=density, constitutive=constitutive)
    points = model.X
    left = select.nodes_on_side(points, 2, "min")
    right = select.nodes_on_side(points, 2, "max")
    model.fixed[left] = True
    held = np.array([[0.0, 0.0, 1.0]]) if slide else None  # a roller face: only the axial component imposed
    model.prescribed.append(PrescribedDisplacement(right, np.array([0.0, 0.0, displacement]), 0.0, ramp_time, held))
    spacing = h / 2 ** (level + quadratic)  # the node spacing of the level
    line, coord = _line_nodes(points, {1: 0.0, 0: 0.5}, 2, 0.25 * spacing)
    kind = "extension" if displacement > 0 else "compression"
    return Case(f"cylinder_{kind}", model, line, coord, ramp_time)


def zhang_cube_shear(n_cells: int = 8, displacement: float = 0.5, constitutive: str = "neo_hookean",
                     E: float = 3000.0, nu: float = 0.49, density: float = 1000.0,
                     ramp_time: float = 1.0, level: int = 0, quadratic: bool = False) -> Case:
    mesh = procedural.cube(2.0, n_cells)
    model = _level_model(mesh, level, quadratic, E=E, nu=nu, density=density, constitutive=constitutive)
    points = model.X
    model.fixed[select.nodes_on_side(points, 1, "min")] = True
    top = select.nodes_on_side(points, 1, "max")
    model.prescribed.append(PrescribedDisplacement(top, np.array([0.0, 0.0, displacement]), 0.0, ramp_time))
    tol = 0.25 * 2.0 / n_cells / 2 ** (level + quadratic)
    line, coord = _line_nodes(points, {0: 2.0, 1: 1.0}, 2, tol)
    return Case("cube_shear", model, line, coord, ramp_time, component=2)


def zhang_cube_stretch(n_cells: int = 8, displacement: float = 0.3, constitutive: str = "neo_hookean",
                       E: float = 3000.0, nu: float = 0.49, density: float = 1000.0,
                       ramp_time: float = 1.0, level: int = 0, quadratic: bool = False) -> Case:
    """The cube stretched along y by ``displacement`` [m] (module docstring); ``n_cells`` even, so the line exists."""
    if n_cells % 2:
        raise ValueError(f"zhang_cube_stretch: n_cells must be even (the line runs at z = 1 m); got {n_cells}")
    mesh = procedural.cube(2.0, n_cells)
    model = _level_model(mesh, level, quadratic, E=E, nu=nu, density=density, constitutive=constitutive)
    points = model.X
    model.fixed[select.nodes_on_side(points, 1, "min")] = True
    top = select.nodes_on_side(points, 1, "max")
    model.prescribed.append(PrescribedDisplacement(top, np.array([0.0, displacement, 0.0]), 0.0, ramp_time))
    tol = 0.25 * 2.0 / n_cells / 2 ** (level + quadratic)
    line, coord = _line_nodes(points, {0: 2.0, 2: 1.0}, 1, tol)
    return Case("cube_stretch", model, line, coord, ramp_time, component=0)


def zhang_case(name: str, cylinder_h: float, cube_cells: int, level: int = 0, quadratic: bool = False) -> Case:
    """The report's case ``name`` (cylinder_extension, cylinder_compression: +-0.4 m; cube_shear, cube_stretch) at
    mesh ``level``."""
    if name == "cube_shear":
        return zhang_cube_shear(n_cells=cube_cells, level=level, quadratic=quadratic)
    if name == "cube_stretch":
        return zhang_cube_stretch(n_cells=cube_cells, level=level, quadratic=quadratic)
    displacement = {"cylinder_extension": 0.4, "cylinder_compression": -0.4}[name]
    return zhang_cylinder(h=cylinder_h, displacement=displacement, level=level, quadratic=quadratic)


def start_positions(model) -> np.ndarray:
    """Rest positions with every kinematic node at its final target: the x_0 of Qian eq. 4.45."""
    x = model.X.copy()
    idx, target = model.kinematic_targets(np.inf)
    x[idx] = target
    return x


def variational_error(model, x, x_ref) -> float:
    """Qian eq. 4.45: (f(x) - f(x*)) / (f(x_0) - f(x*)) on the quasi-static objective
    f = E(x) - f_ext . x, with x* the reference solution and x_0 = :func:`start_positions`."""
    f_ext = model.nodal_external_force()

    def f(y):
        return elastic.elastic_energy(model, y) - float(np.sum(f_ext * y))

    f_star = f(x_ref)
    return float((f(x) - f_star) / (f(start_positions(model)) - f_star))


def relative_l2(u, u_ref) -> float:
    """||u - u_ref|| / ||u_ref|| over all nodes (displacements (n, 3))."""
    return float(np.linalg.norm(u - u_ref) / max(np.linalg.norm(u_ref), 1e-300))


def zhang_cnn_cube() -> tuple[Model, int]:
    """Zhang §4.3.2.2's cube for the CNN: 11 x 11 x 11 nodes (6,000 tets), 1 m, side faces fixed, 100 Pa normal
    load on the top face, E = 3,500 Pa, nu = 0.45, rho = 1,060 kg/m^3; with the index of the top face's centre node."""
    mesh = procedural.box((1.0, 1.0, 1.0), (10, 10, 10))
    model = Model.from_mesh(mesh, E=3500.0, nu=0.45, density=1060.0)
    for axis in (0, 1):
        for side in ("min", "max"):
            model.fixed[select.nodes_on_side(mesh.points, axis, side)] = True
    top = select.nodes_on_side(mesh.points, 2, "max")
    model.external_force = np.zeros_like(mesh.points)
    model.external_force[top, 2] = -100.0 * 1.0 / top.size  # 100 Pa on the 1 m^2 top face
    return model, int(np.argmin(np.linalg.norm(mesh.points - [0.5, 0.5, 1.0], axis=1)))
