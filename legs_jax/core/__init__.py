"""The pure core: the problem format (``problem``), keys (``keys``), exact samplers
(``sampling``), the rollout engine (``engine``) and its compiled programs
(``_programs``), our stopping bound (``stopping``), the methods (``methods/``) and
their NumPy reference (``reference``). Nothing here writes results or draws; the
sweep, the report and the online session build on it.

Importing this package imports none of its modules (``problem`` is read by the
precompute step without JAX).
"""
