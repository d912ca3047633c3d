"""tissuerender: offline simulation -> rendering -> reporting of surgical soft tissue.

Python API (the CLI is a thin layer over it)::

    import tissuerender
    scene = tissuerender.load_scene("scenes/default.toml")   # validated Scene or SceneError
    print(tissuerender.make_plan(scene).describe())          # the stages that will run, and why
    tissuerender.render(scene, "out/")                       # frames + manifest.json
"""
from tissuerender.errors import SceneError, UserError
from tissuerender.scene import Scene, load_scene

__version__ = "0.1.0"
__all__ = ["Scene", "SceneError", "UserError", "load_scene", "make_plan", "render", "render_image", "__version__"]


def __getattr__(name):
    # The pipeline pulls in numba kernels; import it only when a render is asked for.
    if name == "render":
        from tissuerender import pipeline

        return pipeline.render
    if name == "render_image":
        from tissuerender import pipeline

        return pipeline.render_image
    if name == "make_plan":
        from tissuerender.plan import make_plan

        return make_plan
    raise AttributeError(f"module 'tissuerender' has no attribute {name!r}")
