"""Objects (pipeline stage ``objects``): masks, object-only 3DGS, watertight meshes, collision, alignment."""

from .errors import ObjectsError

__all__ = ["ObjectsError"]
