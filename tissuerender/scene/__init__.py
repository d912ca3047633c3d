"""Scene files: schema (``schema``) and loading with precise errors (``load``)."""
from tissuerender.scene.load import Scene, load_scene

__all__ = ["Scene", "load_scene"]
