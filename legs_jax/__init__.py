"""legs_jax."""
