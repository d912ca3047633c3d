"""Smooth render surfaces of implicit (signed-distance) shapes: the zero level set contoured on a grid finer
than the tets (VTK's flying edges, Schroeder et al. 2015), Taubin-smoothed (Taubin 1995) and projected back
onto the level set, so an organ is drawn without the tet mesh's voxel staircase. The surface is embedded in
the tets by the caller (:func:`sim.mesh.embed.embed_points`)."""
from __future__ import annotations

import numpy as np

from sim.errors import MeshError
from sim.mesh.surface import box_uv, taubin_smooth, vertex_normals
from sim.mesh.types import SurfaceMesh

# at most this many grid samples (the liver of scenes/liver_probe.toml needs about 1.1e6)
MAX_SAMPLES = 8_000_000


def contour(sdf, bounds_lo, bounds_hi, pitch: float, source: str = "procedural:sdf") -> SurfaceMesh:
    """The closed triangle surface ``{p : sdf(p) = 0}`` sampled on a grid of spacing ``pitch`` [m] padded by two
    cells around the bounds (so the level set closes), triangles counter-clockwise seen from outside."""
    from vtkmodules.util.numpy_support import numpy_to_vtk, vtk_to_numpy
    from vtkmodules.vtkCommonDataModel import vtkImageData
    from vtkmodules.vtkFiltersCore import vtkFlyingEdges3D

    lo = np.asarray(bounds_lo, dtype=np.float64) - 2.0 * pitch
    hi = np.asarray(bounds_hi, dtype=np.float64) + 2.0 * pitch
    dims = np.ceil((hi - lo) / pitch).astype(int) + 1
    if np.prod(dims.astype(float)) > MAX_SAMPLES:
        raise MeshError(f"{source}: a render surface at {pitch:.3g} m needs {int(np.prod(dims.astype(float)))} grid "
                        f"samples, at most {MAX_SAMPLES}; use a larger cell_size or less render_subdivision")
    axes = [lo[a] + pitch * np.arange(dims[a]) for a in range(3)]
    Z, Y, X = np.meshgrid(axes[2], axes[1], axes[0], indexing="ij")  # VTK point order: x fastest
    values = sdf(np.stack([X.ravel(), Y.ravel(), Z.ravel()], axis=1))
    image = vtkImageData()
    image.SetDimensions(*(int(d) for d in dims))
    image.SetOrigin(*lo)
    image.SetSpacing(pitch, pitch, pitch)
    image.GetPointData().SetScalars(numpy_to_vtk(np.ascontiguousarray(values, dtype=np.float64), deep=True))
    flying_edges = vtkFlyingEdges3D()
    flying_edges.SetInputData(image)
    flying_edges.SetValue(0, 0.0)
    flying_edges.ComputeNormalsOff()
    flying_edges.ComputeGradientsOff()
    flying_edges.ComputeScalarsOff()
    flying_edges.Update()
    poly = flying_edges.GetOutput()
    if poly.GetNumberOfPolys() == 0:
        raise MeshError(f"{source}: the shape has no surface at grid spacing {pitch:.3g} m")
    points = vtk_to_numpy(poly.GetPoints().GetData()).astype(np.float64).reshape(-1, 3)
    triangles = vtk_to_numpy(poly.GetPolys().GetConnectivityArray()).astype(np.int64).reshape(-1, 3)
    used, local = np.unique(triangles, return_inverse=True)
    points, triangles = points[used], local.reshape(-1, 3)
    p = points[triangles]
    volume = np.einsum("ij,ij->", np.cross(p[:, 0], p[:, 1]), p[:, 2]) / 6.0
    if volume < 0.0:  # flying edges orients by the scalar gradient; the SDF grows outwards, so flip if inward
        triangles = triangles[:, [0, 2, 1]]
    return SurfaceMesh(points, triangles, source=source)


def project_to_level_set(sdf, points: np.ndarray, eps: float, steps: int = 3) -> np.ndarray:
    """Newton steps ``p <- p - f(p) grad f / |grad f|^2`` (central differences of width ``2 eps``) onto
    ``f = 0``; each step's move is limited to ``10 eps`` per vertex so a vertex near a crease cannot jump."""
    p = points.copy()
    for _ in range(steps):
        g = np.empty_like(p)
        for a in range(3):
            d = np.zeros(3)
            d[a] = eps
            g[:, a] = (sdf(p + d) - sdf(p - d)) / (2.0 * eps)
        move = -(sdf(p) / np.maximum((g * g).sum(axis=1), 1e-12))[:, None] * g
        length = np.linalg.norm(move, axis=1, keepdims=True)
        p += move * np.minimum(1.0, 10.0 * eps / np.maximum(length, 1e-300))
    return p


def smooth_surface(sdf, bounds_lo, bounds_hi, pitch: float, source: str = "procedural:sdf",
                   iterations: int = 10) -> SurfaceMesh:
    """Contour, Taubin-smooth (``iterations`` lambda/mu pairs: the flying-edges triangles are irregular,
    their normals jump by tens of degrees between neighbours) and project back onto the level set (Taubin's
    small volume change undone). Normals are the area-weighted vertex normals; UVs box-projected in metres."""
    surface = taubin_smooth(contour(sdf, bounds_lo, bounds_hi, pitch, source), iterations=iterations)
    points = project_to_level_set(sdf, surface.points, 0.05 * pitch)
    normals = vertex_normals(points, surface.triangles)
    return SurfaceMesh(points, surface.triangles, normals=normals, uv=box_uv(points, normals), source=source)
