"""What a result's bits can depend on besides the code: the processor (model and
instruction-set class: Embree, NumPy and XLA pick their kernels by it) and the
versions of the packages that compute."""

from __future__ import annotations

import functools
import platform

__all__ = ["machine"]


@functools.cache
def _machine() -> tuple[tuple[str, str], ...]:
    """The processor (model and instruction-set class) and the versions of the
    packages that can change a build's bits."""
    from importlib import metadata

    flags: set[str] = set()
    model = ""
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                key, _, val = line.partition(":")
                key = key.strip()
                if key == "model name" and not model:
                    model = val.strip()
                elif key == "flags" and not flags:
                    flags = set(val.split())
                if model and flags:
                    break
    except OSError:
        pass
    model = model or platform.processor()
    if "avx512f" in flags:
        isa = "AVX-512"
    elif "avx2" in flags:
        isa = "AVX2"
    elif "sse4_2" in flags:
        isa = "SSE4.2"
    else:
        isa = platform.machine() or "unknown"
    out = {"cpu": model or "unknown", "isa": isa, "machine": platform.machine()}
    for pkg in (
        "legs_jax",
        "numpy",
        "scipy",
        "jax",
        "jaxlib",
        "flax",
        "trimesh",
        "embreex",
        "manifold3d",
        "pandas",
        "pyarrow",
    ):
        try:
            out[pkg] = metadata.version(pkg)
        except metadata.PackageNotFoundError:
            out[pkg] = "absent"
    return tuple(out.items())


def machine() -> dict[str, str]:
    """The processor (model and instruction-set class) and the versions of the
    packages that can change a build's bits (read once a process)."""
    return dict(_machine())
