"""Monte-Carlo localization of a camera in a prior semmap map (``semmap localize``).

Stages: :mod:`~semmap.localization.prior` (lookup grids of the map, once per map),
:mod:`~semmap.localization.motion` (relative motion with noise; 6-DoF or ground robot),
:mod:`~semmap.localization.observation` (scan of a frame; semantic / geometry / the paper's cosine score),
:mod:`~semmap.localization.filter` (the particle filter), :mod:`~semmap.localization.run` (a run over a sequence)
and :mod:`~semmap.localization.outputs` (trajectory, report, particle plots).
"""
