"""semmap: RGB-D sequences to 3D semantic maps (semantic OctoMap, voxel grids, object maps)."""

__version__ = "0.1.0"
