"""precompute."""
