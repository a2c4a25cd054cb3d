"""What a mapping run does around its frame loop (``semmap.pipeline``): getting ready, writing the outputs, and
checkpoints to resume from."""
