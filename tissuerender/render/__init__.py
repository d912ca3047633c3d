"""The CPU deferred renderer: raster -> G-buffer -> shade (Qian ch. 6–7).

``tissuerender.render`` is both this package and the API call ``tissuerender.render(scene, out_dir)``:
Python binds a subpackage to its parent's attribute of the same name on import, so the package is
made callable and forwards the call to :func:`tissuerender.pipeline.render`.
"""
import sys
import types

from tissuerender.render.frame import AreaLight, Camera, FrameResult, RenderObject, RenderSettings, render_frame

__all__ = ["AreaLight", "Camera", "FrameResult", "RenderObject", "RenderSettings", "render_frame"]


class _RenderPackage(types.ModuleType):
    def __call__(self, scene, out_dir, **kwargs):
        """Render ``scene`` into ``out_dir`` (see :func:`tissuerender.pipeline.render`)."""
        from tissuerender.pipeline import render

        return render(scene, out_dir, **kwargs)


sys.modules[__name__].__class__ = _RenderPackage
