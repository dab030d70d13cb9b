"""The runtime beside the pure core: what turns :mod:`legs_jax.core`'s functions
into programs and runs them.

- :mod:`~legs_jax.runtime.rollouts`: :func:`run` (validation, batching, jit,
  sharding over devices, progress, collection into a :class:`RunResult`) and the
  compiled programs it shares (:func:`compiled`, :func:`compiled_checks`);
- :mod:`~legs_jax.runtime.programs`: programs traced and compiled once per
  machine and kept on disk beside JAX's compilation cache;
- :mod:`~legs_jax.runtime.conformance`: the checks a method must pass before a
  sweep runs it.

The core never jits, writes to disk or keeps global state; the mctx convention
(the library is pure, the caller compiles) with the caller in this package.
"""

from legs_jax.runtime.rollouts import (
    RunResult,
    compile_seconds,
    compiled,
    compiled_checks,
    mini_batch_rows,
    run,
    table_rows,
    trace_counts,
)

__all__ = [
    "RunResult",
    "compile_seconds",
    "compiled",
    "compiled_checks",
    "mini_batch_rows",
    "run",
    "table_rows",
    "trace_counts",
]
