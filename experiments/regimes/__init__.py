"""When does LEGS win? A map of regimes."""
