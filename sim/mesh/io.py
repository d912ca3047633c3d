"""Reading meshes: tet meshes through meshio (gmsh 1 with :mod:`sim.mesh.formats`), triangle surfaces
through trimesh (VTK POLYDATA and gmsh 1 triangles with :mod:`sim.mesh.formats`), and closed surfaces
turned into tet meshes by voxelisation. Every problem raises :class:`MeshError` naming the file.

Which file is a surface: ``.ply``, ``.obj``, ``.stl``, ``.vtp`` always; a ``.vtk`` whose header says
``DATASET POLYDATA``; a gmsh 1 ``.msh`` without tetrahedra (``is_surface_file``)."""
from __future__ import annotations

import contextlib
import io as io_module
from pathlib import Path

import meshio
import numpy as np

from sim.errors import MeshError
from sim.mesh.formats import is_gmsh1, is_vtk_polydata, read_gmsh1, read_vtk_polydata
from sim.mesh.procedural import KUHN, _compact, _grid, _snap_boundary, orient, signed_volumes
from sim.mesh.types import SurfaceMesh, TetMesh

# the one table of mesh file suffixes (the scene loader checks scene paths against it)
TET_SUFFIXES = (".msh", ".vtu", ".vtk", ".mesh")
SURFACE_SUFFIXES = (".ply", ".obj", ".stl", ".vtp")
# suffixes that hold either a tet mesh or a surface, told apart by the content (is_surface_file)
EITHER_SUFFIXES = (".vtk", ".msh")


def is_surface_file(path) -> bool:
    """Whether a body's mesh file is a triangle surface (voxelised into tets) rather than a tet mesh.

    Unreadable files count as tet meshes, so the tet reader reports what is wrong with them."""
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix in SURFACE_SUFFIXES:
        return True
    if suffix not in EITHER_SUFFIXES or not path.is_file():
        return False
    try:
        if suffix == ".vtk":
            return is_vtk_polydata(path)
        if not is_gmsh1(path):
            return False
        _, tets, triangles = read_gmsh1(path)
    except (OSError, MeshError):
        return False
    return tets.shape[0] == 0 and triangles.shape[0] > 0


def _check_file(path: Path, suffixes) -> None:
    if path.suffix.lower() not in suffixes:
        raise MeshError(f"{path}: unsupported mesh format {path.suffix!r}; expected one of {', '.join(suffixes)}")
    if not path.is_file():
        raise MeshError(f"{path}: mesh file not found")
    if path.stat().st_size == 0:
        raise MeshError(f"{path}: the mesh file is empty")


def clean_tets(points: np.ndarray, tets: np.ndarray, source: str) -> tuple[TetMesh, dict]:
    """Validate and repair raw arrays: reject NaN/inf coordinates, out-of-range indices and
    zero-volume tets; flip negatively oriented tets; drop unreferenced nodes. Returns the mesh and
    ``{"flipped": int, "unreferenced_removed": int}``."""
    points = np.asarray(points, dtype=np.float64)
    tets = np.asarray(tets, dtype=np.int64)
    if points.ndim != 2 or points.shape[1] != 3:
        raise MeshError(f"{source}: expected (n, 3) node coordinates, found shape {points.shape}")
    if tets.size == 0:
        raise MeshError(f"{source}: the mesh has no tetrahedra")
    bad = np.flatnonzero(~np.isfinite(points).all(axis=1))
    if bad.size:
        raise MeshError(f"{source}: node {bad[0]} has a non-finite coordinate {points[bad[0]].tolist()}")
    out = np.flatnonzero((tets < 0).any(axis=1) | (tets >= points.shape[0]).any(axis=1))
    if out.size:
        raise MeshError(f"{source}: tet {out[0]} references node {tets[out[0]].tolist()} but the mesh has "
                        f"{points.shape[0]} nodes")
    vol = signed_volumes(points, tets)
    scale = np.abs(vol).mean()
    flat = np.flatnonzero(np.abs(vol) <= 1e-12 * max(scale, 1e-300))
    if flat.size:
        raise MeshError(f"{source}: tet {flat[0]} has zero volume ({vol[flat[0]]:.3e} m^3); "
                        f"{flat.size} degenerate tet(s) in all")
    flipped = int((vol < 0).sum())
    tets = orient(points, tets)
    n_before = points.shape[0]
    points, tets = _compact(points, tets)
    info = {"flipped": flipped, "unreferenced_removed": n_before - points.shape[0]}
    return TetMesh(points, tets, source=source), info


def read_tet_mesh(path) -> TetMesh:
    """A tet mesh from .msh, .vtu, .vtk or .mesh (meshio); ``mesh.source`` is the path.

    Negatively oriented tets are flipped and unreferenced nodes removed (counted in ``mesh.repairs``);
    anything unusable raises :class:`MeshError`.
    """
    path = Path(path)
    _check_file(path, TET_SUFFIXES)
    if path.suffix.lower() == ".msh" and is_gmsh1(path):
        nodes, tets, _ = read_gmsh1(path)
        if tets.shape[0] == 0:
            raise MeshError(f"{path}: no tetrahedra in the gmsh 1 file (element type 4); expected a tet mesh")
        mesh, info = clean_tets(nodes, tets, str(path))
        mesh.repairs = info
        return mesh
    chatter = io_module.StringIO()
    try:
        # meshio prints its own complaints and may even call sys.exit on unreadable input.
        with contextlib.redirect_stdout(chatter), contextlib.redirect_stderr(chatter):
            m = meshio.read(path)
    except (Exception, SystemExit) as e:
        detail = str(e)[:200] if not isinstance(e, SystemExit) else chatter.getvalue().strip()[:200]
        raise MeshError(f"{path}: cannot read the mesh ({type(e).__name__}: {detail})") from None
    blocks = [c.data for c in m.cells if c.type == "tetra"]
    if not blocks:
        found = sorted({c.type for c in m.cells}) or ["no cells"]
        raise MeshError(f"{path}: no tetrahedra in the file (found {', '.join(found)}); expected a tet mesh")
    mesh, info = clean_tets(m.points[:, :3] if m.points.shape[1] >= 3 else m.points,
                            np.concatenate(blocks), str(path))
    mesh.repairs = info
    return mesh


def read_surface(path) -> SurfaceMesh:
    """A triangle surface from .ply, .obj or .stl (trimesh), keeping the file's vertex normals and UVs, or from
    a VTK POLYDATA ``.vtp``/``.vtk`` or a gmsh 1 ``.msh`` holding triangles (:mod:`sim.mesh.formats`)."""
    path = Path(path)
    _check_file(path, SURFACE_SUFFIXES + EITHER_SUFFIXES)
    suffix = path.suffix.lower()
    if suffix in (".vtp", ".vtk"):
        points, triangles, normals = read_vtk_polydata(path)
        return _checked_surface(path, points, triangles, normals)
    if suffix == ".msh":
        if not is_gmsh1(path):
            raise MeshError(f"{path}: a surface .msh must be a gmsh 1 file ($NOD/$ELM) holding triangles")
        points, _, triangles = read_gmsh1(path)
        if triangles.shape[0] == 0:
            raise MeshError(f"{path}: no triangles in the gmsh 1 file (element type 2)")
        return _checked_surface(path, points, triangles, None)
    import trimesh  # lazy: seconds to import, and only surface files need it

    try:
        tm = trimesh.load(path, force="mesh", process=False, maintain_order=True)
    except Exception as e:
        raise MeshError(f"{path}: cannot read the surface ({type(e).__name__}: {str(e)[:200]})") from None
    if not isinstance(tm, trimesh.Trimesh) or len(tm.faces) == 0:
        raise MeshError(f"{path}: no triangles in the file")
    points = np.asarray(tm.vertices, dtype=np.float64)
    if not np.isfinite(points).all():
        raise MeshError(f"{path}: non-finite vertex coordinates")
    normals = _file_normals(path, tm, points.shape[0])
    uv = None
    visual_uv = getattr(tm.visual, "uv", None)
    if visual_uv is not None and len(visual_uv) == len(points):
        uv = np.asarray(visual_uv, dtype=np.float64)
    return SurfaceMesh(points, np.asarray(tm.faces), normals=normals, uv=uv, source=str(path))


def _checked_surface(path: Path, points, triangles, normals) -> SurfaceMesh:
    """A surface of the nodes its triangles use (others dropped), with finite coordinates and valid indices."""
    if not np.isfinite(points).all():
        raise MeshError(f"{path}: non-finite vertex coordinates")
    if triangles.size and (triangles.min() < 0 or triangles.max() >= points.shape[0]):
        raise MeshError(f"{path}: a triangle references a node outside the {points.shape[0]} nodes")
    used, local = np.unique(triangles, return_inverse=True)
    if normals is not None:
        normals = normals[used]
        length = np.linalg.norm(normals, axis=1, keepdims=True)
        normals = normals / np.where(length > 0, length, 1.0) if np.isfinite(normals).all() else None
    return SurfaceMesh(points[used], local.reshape(-1, 3), normals=normals, source=str(path))


def _file_normals(path: Path, tm, n: int) -> np.ndarray | None:
    """Vertex normals stored in the file itself (trimesh recomputes its own, so read them here):
    PLY ``nx, ny, nz`` vertex properties, OBJ ``vn`` records referenced by the faces; STL has none."""
    suffix = path.suffix.lower()
    normals = None
    if suffix == ".ply":
        data = tm.metadata.get("_ply_raw", {}).get("vertex", {}).get("data", {})
        # a dict of columns (ASCII PLY) or a structured array (binary PLY, e.g. written by trimesh)
        names = data.dtype.names or () if isinstance(data, np.ndarray) else tuple(data)
        if all(k in names for k in ("nx", "ny", "nz")):
            normals = np.concatenate([np.asarray(data[k], dtype=np.float64).reshape(-1, 1) for k in ("nx", "ny", "nz")], 1)
    elif suffix == ".obj":
        vn, assigned = [], {}
        for line in path.read_text(errors="replace").splitlines():
            parts = line.split()
            if not parts:
                continue
            if parts[0] == "vn" and len(parts) >= 4:
                vn.append([float(v) for v in parts[1:4]])
            elif parts[0] == "f":
                for corner in parts[1:]:
                    fields = corner.split("/")
                    if len(fields) == 3 and fields[2]:
                        assigned[int(fields[0]) - 1] = int(fields[2]) - 1
        if vn and len(assigned) == n:
            vn = np.asarray(vn)
            normals = np.empty((n, 3))
            for v, k in assigned.items():
                normals[v] = vn[k]
    if normals is None or normals.shape != (n, 3) or not np.isfinite(normals).all():
        return None
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    return normals / np.where(length > 0, length, 1.0)


def tetrahedralize_surface(surface: SurfaceMesh, h: float) -> TetMesh:
    """Tets filling a closed surface: voxelise (trimesh) at pitch ``h``, split voxels 6 ways, and snap
    boundary nodes onto the surface with the no-inversion guard of :func:`sim.mesh.procedural.from_sdf`."""
    import trimesh  # lazy: seconds to import, and only surface files need it

    tm = trimesh.Trimesh(surface.points, surface.triangles, process=True)
    if not tm.is_watertight:
        raise MeshError(f"{surface.source}: the surface is not closed (watertight); cannot fill it with tets")
    if not np.isfinite(h) or h <= 0:
        raise MeshError(f"{surface.source}: cell size must be positive, found {h}")
    lo = tm.bounds[0] - h
    cells = np.ceil((tm.bounds[1] + h - lo) / h).astype(int)
    if np.prod(cells.astype(float)) * 6 > 3e6:
        raise MeshError(f"{surface.source}: cell size {h} m is too small for this surface (over 3e6 tets)")
    points, corners = _grid(lo, cells, np.full(3, h))
    tets = corners[:, KUHN].reshape(-1, 4)
    inside = tm.contains(points[tets].mean(axis=1))
    tets = tets[inside]
    if tets.size == 0:
        raise MeshError(f"{surface.source}: no voxel lies inside the surface at cell size {h} m")
    points, tets = _compact(points, tets)
    tets = orient(points, tets)

    def sdf(p):
        closest, distance, _ = trimesh.proximity.closest_point(tm, p)
        return np.where(tm.contains(p), -distance, distance)

    points = _snap_boundary(points, tets, sdf, h)
    return TetMesh(points, tets, source=surface.source)
