"""JAX's persistent compilation cache, shared by the sweep and the online CLI."""

from __future__ import annotations

import os


def compile_cache(option: str | None) -> str | None:
    """Turn on JAX's persistent compilation cache (results do not depend on it).

    ``option``: "off", a folder, or None for ``$JAX_COMPILATION_CACHE_DIR``,
    ``$LEGS_JAX_CACHE_DIR`` or ``$XDG_CACHE_HOME/legs_jax/jax``, the first that is
    set. Returns the folder used, None when off or when the folder cannot be made
    (a read-only home: run without the cache).
    """
    if option == "off":
        return None
    path = (
        option
        or os.environ.get("JAX_COMPILATION_CACHE_DIR")
        or os.environ.get("LEGS_JAX_CACHE_DIR")
    )
    if not path:
        base = os.environ.get("XDG_CACHE_HOME") or os.path.join(
            os.path.expanduser("~"), ".cache"
        )
        path = os.path.join(base, "legs_jax", "jax")
    try:
        os.makedirs(path, exist_ok=True)
    except OSError:
        return None
    import jax

    jax.config.update("jax_compilation_cache_dir", path)
    # Every program, however quickly it compiles (JAX's default keeps only those
    # of a second or more): a repeated run should compile nothing.
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    return path
