"""When does LEGS win? A map of regimes (issue 27)."""
