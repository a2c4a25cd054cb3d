"""maps stage."""
