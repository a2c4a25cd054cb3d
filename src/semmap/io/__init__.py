"""File formats: OctoMap .bt/.ot, the lossless native map, PLY, trajectories; all writes atomic."""
