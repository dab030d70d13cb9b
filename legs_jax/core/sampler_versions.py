"""Names of the exact Beta samplers, without JAX (the sweep's manifests record the
one a result was made with; :mod:`legs_jax.core.beta_sampler` is the current one)."""

# What manifests record as the Beta sampler of a run: Cheng's log-logistic
# rejection (algorithm BA), :func:`legs_jax.core.beta_sampler.beta_rows_v2`.
SAMPLER_VERSION = "cheng-ba-1"
# The sampler before it: legs_jax.core.sampling.beta_rows (Ga / (Ga + Gb) with
# Marsaglia-Tsang gammas, a Box-Muller pair for try 0, erf_inv normals after).
# Results whose manifests name no sampler were made with it.
PREVIOUS_SAMPLER_VERSION = "marsaglia-tsang-ratio-1"
