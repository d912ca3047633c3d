"""Pictures of the error field on the deformed mesh (issue 17 item 3): for each mesh case of the accuracy report,
the outer surface of the best and of the worst setting (least and largest finite relative L2 error), each
deformed by its own displacement and coloured by the per-node error magnitude ``|u - u_ref|`` [m], side by side.

Two steps, so the pictures come from stored numbers like every other figure of the report:

- :func:`error_fields` (inside the case run, ``cases.run_mesh``) keeps, for the best and the worst point, the
  displacement at the surface nodes, with the reference's and the surface triangles, in the case's JSON (float32
  precision: a picture needs no more), and drops every other point's full displacement;
- :func:`error_field_png` renders one case's stored fields with pyvista off-screen (VTK's OSMesa window on a
  machine with no display, ``docs/report.md``), returning PNG bytes.

Colours: viridis over ``[0, max error of that setting]``, one colour bar per panel (the best setting's error is
orders of magnitude below the worst's: a shared range would show it as one flat colour). Flat, unlit colouring,
so a pixel's colour is the colour map's colour of its interpolated error (the test reads the range back from the
pixels) and the edges sharper than 80 degrees (corners, rims) carry the shape.
"""
from __future__ import annotations

import io
import os

import numpy as np

from sim.mesh.surface import boundary_faces

COLORMAP = "viridis"
PANEL_SIZE = (360, 300)  # pixels per panel (width, height)


def error_fields(model, points: list[dict], u_ref: np.ndarray, error_key: str = "rel_l2") -> dict | None:
    """Pop every point's full displacement (``"_u"``, set by ``measure.mesh_point``) and keep the best and the worst
    finite one's at the surface nodes: ``{"X", "triangles", "u_ref", "panels": [{"which", "setting", "error", "u"}]}``
    (positions in metres, float32-rounded lists); None when no point has a displacement."""
    fields = [(p, p.pop("_u", None)) for p in points]
    finite = [(p, u) for p, u in fields if u is not None and np.isfinite(p.get(error_key, np.nan))]
    if not finite:
        return None
    finite.sort(key=lambda pu: pu[0][error_key])
    faces = boundary_faces(np.asarray(model.tets))
    used, local = np.unique(faces, return_inverse=True)

    def rounded(a):
        return np.asarray(a, dtype=np.float32)[used].astype(float).tolist()

    panels = []
    for which, (p, u) in (("best", finite[0]), ("worst", finite[-1])):
        panels.append({"which": which, "setting": f"{p['integrator']} {p['setting']}", "error": p[error_key],
                       "u": rounded(u)})
    return {"X": rounded(model.X), "triangles": local.reshape(-1, 3).tolist(), "u_ref": rounded(u_ref),
            "error_key": error_key, "panels": panels}


def _offscreen():
    """pyvista, off-screen through VTK's OSMesa window when libOSMesa is there (no X display needed)."""
    import ctypes

    for name in ("libOSMesa.so.8", "libOSMesa.so.6", "libOSMesa.so"):
        try:
            ctypes.CDLL(name)
        except OSError:
            continue
        os.environ.setdefault("VTK_DEFAULT_OPENGL_WINDOW", "vtkOSOpenGLRenderWindow")
        break
    import pyvista as pv

    pv.OFF_SCREEN = True
    return pv


def error_field_image(fields: dict, scalar_bars: bool = True, labels: bool = True) -> np.ndarray:
    """The panels of ``fields`` (``error_fields``) side by side as an (h, w, 3) uint8 image; without the colour bars
    and labels only the meshes' colours are in it (the test reads the colour map's range back from them)."""
    pv = _offscreen()
    X = np.asarray(fields["X"])
    u_ref = np.asarray(fields["u_ref"])
    triangles = np.asarray(fields["triangles"], dtype=np.int64)
    faces = np.hstack([np.full((len(triangles), 1), 3), triangles]).ravel()
    panels = fields["panels"]
    plotter = pv.Plotter(off_screen=True, shape=(1, len(panels)),
                         window_size=(PANEL_SIZE[0] * len(panels), PANEL_SIZE[1]), border=False)
    plotter.set_background("white")
    try:
        for k, panel in enumerate(panels):
            u = np.asarray(panel["u"])
            error = np.linalg.norm(u - u_ref, axis=1)
            mesh = pv.PolyData(X + u, faces)
            mesh.point_data["error"] = error
            plotter.subplot(0, k)
            top = float(error.max()) if error.max() > 0.0 else 1.0
            plotter.add_mesh(mesh, scalars="error", cmap=COLORMAP, clim=(0.0, top), lighting=False,
                             show_scalar_bar=scalar_bars,
                             scalar_bar_args={"title": f"{panel['which']}: error [m]", "vertical": True,
                                              "position_x": 0.8, "position_y": 0.1, "width": 0.07, "height": 0.7,
                                              "fmt": "%.1e",
                                              "color": "black", "title_font_size": 12, "label_font_size": 10})
            edges = mesh.extract_feature_edges(80.0, boundary_edges=False, non_manifold_edges=False)
            plotter.add_mesh(edges, color="black", line_width=1)  # the body's corners and rims
            if labels:
                plotter.add_text(f"{panel['which']}: {panel['setting']}\n{fields['error_key']} {panel['error']:.3g}",
                                 font_size=8, color="black", position="upper_left")
            plotter.view_isometric()
            plotter.reset_camera()
            plotter.camera.zoom(0.8)
        image = plotter.screenshot(return_img=True)
    finally:
        plotter.close()
    return np.asarray(image)[..., :3]


def error_field_png(fields: dict) -> bytes:
    """``error_field_image`` as PNG bytes (matplotlib's writer, no metadata stamp)."""
    import matplotlib.image

    buffer = io.BytesIO()
    matplotlib.image.imsave(buffer, error_field_image(fields), format="png", metadata={"Software": None})
    return buffer.getvalue()
