"""File formats, above the maps: every map's files from its public arrays (``map_files``: OctoMap .ot/.bt, the
lossless native ``.semmap``, PLY), TUM trajectories and sequence folders, objects, checkpoints; all writes atomic
(``semmap.files``)."""
