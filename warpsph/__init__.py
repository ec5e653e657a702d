"""warpsph: DFSPH fluids on NVIDIA Warp with turbulence refinement models."""

__version__ = "0.1.0"

from .errors import SceneError  # noqa: F401
from .scene import Scene, load_scene  # noqa: F401
