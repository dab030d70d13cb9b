"""The pure core: the problem format (``problem``), keys (``keys``), exact samplers
(``sampling``), the rollout loop (``engine``: the environment, one agent step, the
whole loop and the stopping checks), our stopping bound (``stopping``), the
methods (``methods/``) and their NumPy reference (``reference``). Pure functions:
nothing here jits, writes to disk or keeps state between calls; the runtime
(:mod:`legs_jax.runtime`) compiles and runs them, and the sweep, the report and
the online session build on it.

Importing this package imports none of its modules (``problem`` is read by the
precompute step without JAX).
"""
