"""What one frame computes: the renderer's switches (the scene's ``[effects]`` and ``[output]`` keys,
validated in ``tissuerender.scene.schema``, arrive here through ``tissuerender.pipeline.settings_for``)."""
from __future__ import annotations

from dataclasses import dataclass


@dataclass
class RenderSettings:
    """The switches of one frame; each stage of ``frame.render_frame`` runs only when they ask for it."""

    shadows: bool = False
    sss: bool = False
    sss_thickness: str = "vertex"  # thickness rays from the vertices (interpolated) or from every shading point
    ao: bool = False
    mucus_reflection: bool = False
    supersampling: int = 1
    seed: int = 0
    motion: bool = False
    ambient: tuple = (0.0, 0.0, 0.0)  # uniform environment radiance [W m^-2 sr^-1]
    environment_up: tuple = (0.0, 0.0, 0.0)  # SH gradient environment for the mucus reflection
    environment_down: tuple = (0.0, 0.0, 0.0)
    environment_axis: tuple = (0.0, 0.0, 1.0)
    ao_distance: float = 0.02  # occlusion ray length [m]
    ao_samples: int = 8
    jitter: bool = True  # supersampling: each sample at a seeded random point of its cell (False: cell centres)
    fused: bool = True  # numba direct-lighting passes (shade_kernel); False: the NumPy estimator only
    ray_backend: str = "auto"  # "auto" | "embree" | "numba" (tissuerender.renderer.rays)
