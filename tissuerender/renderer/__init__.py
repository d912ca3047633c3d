"""The CPU deferred renderer: raster -> G-buffer -> shade (Qian ch. 6–7).

The application's call ``tissuerender.render(scene, out_dir)`` is :func:`tissuerender.pipeline.render`;
this package renders one frame of triangle meshes (:func:`render_frame`) and knows nothing of scenes.
"""
from tissuerender.renderer.frame import AreaLight, Camera, FrameResult, RenderObject, RenderSettings, render_frame

__all__ = ["AreaLight", "Camera", "FrameResult", "RenderObject", "RenderSettings", "render_frame"]
