"""tissuerender: offline simulation -> rendering -> reporting of surgical soft tissue.

Python API (the CLI is a thin layer over it)::

    import tissuerender
    scene = tissuerender.load_scene("scenes/default.toml")   # validated Scene or SceneError
    print(tissuerender.make_plan(scene).describe())          # the stages that will run, and why
    tissuerender.render(scene, "out/")                       # frames + manifest.json
"""
import sim  # noqa: F401  (numba's cache stamps and inliner, sim.numba_cache and sim.numba_inline, before any kernel)
from tissuerender.errors import SceneError, UserError
from tissuerender.pipeline import render, render_image, render_passes
from tissuerender.plan import make_plan
from tissuerender.scene import Scene, load_scene

__version__ = "0.1.0"
__all__ = ["Scene", "SceneError", "UserError", "load_scene", "make_plan", "render", "render_image", "render_passes", "__version__"]
