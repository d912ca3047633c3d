"""The CPU deferred renderer: raster -> G-buffer -> shade (Qian ch. 6–7).

The application's call ``tissuerender.render(scene, out_dir)`` is :func:`tissuerender.pipeline.render`;
this package renders one frame of triangle meshes (:func:`render_frame`) and knows nothing of scenes.
"""
from tissuerender.renderer.camera import Camera
from tissuerender.renderer.frame import FrameResult, RenderObject, render_frame
from tissuerender.renderer.light import AreaLight
from tissuerender.renderer.settings import RenderSettings

__all__ = ["AreaLight", "Camera", "FrameResult", "RenderObject", "RenderSettings", "render_frame"]
