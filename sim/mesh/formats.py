"""Mesh formats meshio and trimesh do not read: gmsh's original ``$NOD``/``$ELM`` format (version 1) and
VTK POLYDATA surfaces (legacy ``.vtk`` with ``DATASET POLYDATA``, XML ``.vtp``, read with VTK itself).

gmsh 1 (gmsh reference manual, "Legacy formats", MSH file format version 1)::

    $NOD
    number-of-nodes
    node-number x y z          (node numbers are labels: any positive integers, in any order)
    $ENDNOD
    $ELM
    number-of-elements
    elm-number elm-type reg-phys reg-elem number-of-nodes node-number-list
    $ENDELM

Element types kept: 2 (3-node triangle) and 4 (4-node tetrahedron); points (15), lines (1) and the other
types are skipped. Every problem raises :class:`MeshError` naming the file and the line.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from sim.errors import MeshError

GMSH1_TRIANGLE, GMSH1_TET = 2, 4


def is_gmsh1(path: Path) -> bool:
    """Whether ``path`` starts with gmsh 1's ``$NOD`` section (gmsh 2 and 4 start with ``$MeshFormat``)."""
    with open(path, "rb") as f:
        head = f.read(64).lstrip()
    return head.startswith(b"$NOD")


def is_vtk_polydata(path: Path) -> bool:
    """Whether a legacy ``.vtk`` file declares ``DATASET POLYDATA`` (its header is ASCII even in binary files)."""
    with open(path, "rb") as f:
        head = f.read(1024).split(b"\n")[:5]
    return any(line.strip().upper().startswith(b"DATASET POLYDATA") for line in head)


def read_gmsh1(path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Nodes ``(n, 3)``, tets ``(m, 4)`` and triangles ``(k, 3)`` (0-based, into the nodes) of a gmsh 1 file.

    Node labels are mapped to 0-based indices in the order of the ``$NOD`` section.

    >>> import tempfile, pathlib
    >>> p = pathlib.Path(tempfile.mkdtemp()) / "t.msh"
    >>> _ = p.write_text("$NOD\\n4\\n1 0 0 0\\n2 1 0 0\\n3 0 1 0\\n9 0 0 1\\n$ENDNOD\\n"
    ...                  "$ELM\\n1\\n1 4 1 1 4 1 2 3 9\\n$ENDELM\\n")
    >>> nodes, tets, triangles = read_gmsh1(p)
    >>> nodes.shape, tets.tolist(), triangles.shape
    ((4, 3), [[0, 1, 2, 3]], (0, 3))
    """
    path = Path(path)
    try:
        lines = path.read_text(encoding="ascii").splitlines()
    except (UnicodeDecodeError, OSError) as e:
        raise MeshError(f"{path}: cannot read the gmsh 1 file ({type(e).__name__}: {str(e)[:120]})") from None
    rows = [(i + 1, line.split()) for i, line in enumerate(lines) if line.strip()]
    cursor = 0

    def expect(word: str) -> None:
        nonlocal cursor
        if cursor >= len(rows) or rows[cursor][1][0] != word:
            found = " ".join(rows[cursor][1])[:40] if cursor < len(rows) else "the end of the file"
            where = f"line {rows[cursor][0]}" if cursor < len(rows) else "end"
            raise MeshError(f"{path}: {where}: expected {word}, found {found!r}")
        cursor += 1

    def count(section: str) -> int:
        nonlocal cursor
        if cursor >= len(rows) or len(rows[cursor][1]) != 1 or not rows[cursor][1][0].isdigit():
            where = f"line {rows[cursor][0]}" if cursor < len(rows) else "end"
            raise MeshError(f"{path}: {where}: expected the number of {section} after ${section.upper()[:3]}")
        cursor += 1
        return int(rows[cursor - 1][1][0])

    expect("$NOD")
    n_nodes = count("nodes")
    if cursor + n_nodes > len(rows):
        raise MeshError(f"{path}: $NOD announces {n_nodes} nodes, the file ends after {len(rows) - cursor}")
    labels = np.empty(n_nodes, dtype=np.int64)
    nodes = np.empty((n_nodes, 3))
    for j in range(n_nodes):
        line, fields = rows[cursor + j]
        try:
            if len(fields) != 4:
                raise ValueError
            labels[j] = int(fields[0])
            nodes[j] = [float(v) for v in fields[1:]]
        except ValueError:
            raise MeshError(f"{path}: line {line}: expected 'node-number x y z', "
                            f"found {' '.join(fields)[:60]!r}") from None
    cursor += n_nodes
    expect("$ENDNOD")
    expect("$ELM")
    n_elements = count("elements")
    if cursor + n_elements > len(rows):
        raise MeshError(f"{path}: $ELM announces {n_elements} elements, the file ends after {len(rows) - cursor}")
    order = np.argsort(labels, kind="stable")
    sorted_labels = labels[order]
    if np.any(sorted_labels[1:] == sorted_labels[:-1]):
        raise MeshError(f"{path}: node number {sorted_labels[1:][sorted_labels[1:] == sorted_labels[:-1]][0]} "
                        f"appears twice in $NOD")
    cells: dict[int, list] = {GMSH1_TRIANGLE: [], GMSH1_TET: []}
    for j in range(n_elements):
        line, fields = rows[cursor + j]
        try:
            elm_type, n_corner = int(fields[1]), int(fields[4])
            corners = [int(v) for v in fields[5:]]
            if len(corners) != n_corner:
                raise ValueError
        except (ValueError, IndexError):
            raise MeshError(f"{path}: line {line}: expected 'elm-number elm-type reg-phys reg-elem number-of-nodes "
                            f"node-number-list', found {' '.join(fields)[:60]!r}") from None
        if elm_type in cells:
            if n_corner != (3 if elm_type == GMSH1_TRIANGLE else 4):
                raise MeshError(f"{path}: line {line}: element type {elm_type} needs "
                                f"{3 if elm_type == GMSH1_TRIANGLE else 4} nodes, found {n_corner}")
            cells[elm_type].append((line, corners))
    cursor += n_elements
    expect("$ENDELM")

    def indices(items, width):
        if not items:
            return np.zeros((0, width), dtype=np.int64)
        flat = np.array([c for _, corners in items for c in corners], dtype=np.int64)
        pos = np.clip(np.searchsorted(sorted_labels, flat), 0, n_nodes - 1)
        missing = np.flatnonzero(sorted_labels[pos] != flat)
        if missing.size:
            line = items[missing[0] // width][0]
            raise MeshError(f"{path}: line {line}: element names node {flat[missing[0]]}, which $NOD does not list")
        return order[pos].reshape(-1, width)

    return nodes, indices(cells[GMSH1_TET], 4), indices(cells[GMSH1_TRIANGLE], 3)


def read_vtk_polydata(path) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Points ``(n, 3)``, triangles ``(k, 3)`` and point normals (or ``None``) of a VTK POLYDATA surface
    (legacy ``.vtk`` or XML ``.vtp``). Polygons are split into triangles (``vtkTriangleFilter``); vertices,
    lines and strips-as-lines are dropped."""
    from vtkmodules.util.numpy_support import vtk_to_numpy
    from vtkmodules.vtkCommonCore import vtkFileOutputWindow, vtkLogger, vtkOutputWindow
    from vtkmodules.vtkFiltersCore import vtkTriangleFilter
    from vtkmodules.vtkIOLegacy import vtkPolyDataReader
    from vtkmodules.vtkIOXML import vtkXMLPolyDataReader

    path = Path(path)
    legacy = path.suffix.lower() == ".vtk"
    if legacy and not is_vtk_polydata(path):
        raise MeshError(f"{path}: expected a VTK POLYDATA surface ('DATASET POLYDATA' in the header)")
    reader = vtkPolyDataReader() if legacy else vtkXMLPolyDataReader()
    reader.SetFileName(str(path))
    # VTK reports unreadable input on its output window and its logger, not by raising: silence both (a bad file
    # gets one MeshError line, not VTK's log) and check the result.
    sink = vtkFileOutputWindow()
    sink.SetFileName("/dev/null")
    previous = vtkOutputWindow.GetInstance()
    vtkOutputWindow.SetInstance(sink)
    verbosity = vtkLogger.GetCurrentVerbosityCutoff()
    vtkLogger.SetStderrVerbosity(vtkLogger.VERBOSITY_OFF)
    try:
        reader.Update()
        failed = (reader.GetErrorCode() != 0) if hasattr(reader, "GetErrorCode") else False
        triangulate = vtkTriangleFilter()
        triangulate.SetInputConnection(reader.GetOutputPort())
        triangulate.PassVertsOff()
        triangulate.PassLinesOff()
        triangulate.Update()
    finally:
        vtkOutputWindow.SetInstance(previous)
        vtkLogger.SetStderrVerbosity(vtkLogger.ConvertToVerbosity(verbosity))
    poly = triangulate.GetOutput()
    if failed or poly is None or poly.GetNumberOfPoints() == 0:
        raise MeshError(f"{path}: cannot read the VTK surface (no points; is it a valid {path.suffix} POLYDATA file?)")
    points = vtk_to_numpy(poly.GetPoints().GetData()).astype(np.float64).reshape(-1, 3)
    polys = poly.GetPolys()
    if polys.GetNumberOfCells() == 0:
        raise MeshError(f"{path}: no polygons in the file (a surface needs triangles or polygons)")
    connectivity = vtk_to_numpy(polys.GetConnectivityArray()).astype(np.int64)
    triangles = connectivity.reshape(-1, 3)
    normals = None
    data = poly.GetPointData().GetNormals()
    if data is not None and data.GetNumberOfComponents() == 3:
        normals = vtk_to_numpy(data).astype(np.float64).reshape(-1, 3)
    return points, triangles, normals
