"""Segmentation networks of the papers, trained by ``semmap train`` and run through
:class:`~semmap.perception.network.NetworkSegmenter`: FCN-8s, PSPNet, CBAM-PSPNet and the RGB-D multi-scale
network (with its colour-only twin).  :mod:`.registry` builds them by name and reads/writes their weight files."""
