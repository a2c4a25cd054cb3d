"""Wall, floor and ceiling from one depth image and the direction of gravity (``--segmenter structure``)."""
