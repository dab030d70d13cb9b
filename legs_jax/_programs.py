"""Compiled programs of the engine, each made once per process, and traced once
per machine.

:func:`call` runs a jitted function through an executable compiled ahead of time
for its argument shapes (so that compilation is timed apart from running,
:func:`compile_seconds`). Where JAX's persistent compilation cache is on
(:func:`legs_jax._jax_cache.compile_cache`) and the function was described with
:func:`describe`, the traced program is also kept on disk (``jax.export``, in the
cache folder's ``legs_jax-exported/``): a later process deserialises it instead of
tracing and lowering the Python code again (LEGS took 1.5-3 s to trace on a
2-core machine), and its compilation then comes from the persistent cache. Every
call goes through the exported program whenever the cache is on, the first one
included, so the numbers never depend on whether a program was traced here or
loaded; a test checks that they equal those of the plain jitted function.

A kept program is found by the SHA-256 of: the source of every module of
``legs_jax``, the versions of jax, jaxlib, NumPy and SciPy, the function's
description (method, static configuration, devices) and its arguments' shapes,
types and shardings. Only the registered methods (all their functions in
``legs_jax``) are kept: a user's method may depend on code outside the package,
so it is traced anew by each process.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import os
import time
from collections import OrderedDict
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax

_EXECUTABLES: OrderedDict = OrderedDict()
_MAX_EXECUTABLES = 64
_COMPILE_SECONDS = [0.0]
_DESCRIPTIONS: dict[Any, str] = {}
_FOLDER = "legs_jax-exported"


def compile_seconds() -> float:
    """Seconds this process has spent tracing, lowering and compiling (or loading
    from the caches) the programs run through :func:`call`."""
    return _COMPILE_SECONDS[0]


def describe(fn: Callable, name: str | None, *parts: Any) -> Callable:
    """Record a stable description of the jitted ``fn`` (a name and its static
    facts), which lets :func:`call` keep its traced program on disk; returns
    ``fn``. A name of None keeps it off disk."""
    if name is not None:
        _DESCRIPTIONS[fn] = repr((name, *parts))
    return fn


def method_fingerprint(method: Any) -> str | None:
    """The name of a registered method whose functions all live in ``legs_jax``
    (None for any other: it is not kept on disk)."""
    for f in dataclasses.fields(method):
        v = getattr(method, f.name)
        while isinstance(v, functools.partial):
            v = v.func
        if callable(v) and not str(getattr(v, "__module__", "")).startswith(
            "legs_jax."
        ):
            return None
    return str(method.name)


def devices_fingerprint(devices) -> str:
    if devices is None:
        return "default"
    return repr(tuple((d.platform, d.device_kind, d.id) for d in devices))


@functools.lru_cache(maxsize=1)
def _code_fingerprint() -> str:
    import jaxlib
    import numpy
    import scipy

    h = hashlib.sha256()
    root = Path(__file__).resolve().parent
    for p in sorted(root.rglob("*.py")):
        h.update(str(p.relative_to(root)).encode())
        h.update(p.read_bytes())
    for mod in (jax, jaxlib, numpy, scipy):
        h.update(f"{mod.__name__} {mod.__version__}".encode())
    return h.hexdigest()


def _folder() -> Path | None:
    base = jax.config.jax_compilation_cache_dir
    if not base:
        return None
    return Path(base) / _FOLDER


def _exported(fn: Callable, desc: str, folder: Path, leaves, tree):
    """The exported program of ``fn`` flattened over its argument leaves, read
    from ``folder`` or made and written there."""
    from jax import export

    key = hashlib.sha256(
        "\n".join(
            [
                _code_fingerprint(),
                desc,
                str(tree),
                repr([(x.shape, str(x.dtype), repr(x.sharding)) for x in leaves]),
            ]
        ).encode()
    ).hexdigest()
    path = folder / f"{key}.bin"
    if path.is_file():
        try:
            return export.deserialize(bytearray(path.read_bytes()))
        except Exception:  # noqa: BLE001 - a damaged file is made again
            pass

    def flat(*xs):
        return fn(*jax.tree_util.tree_unflatten(tree, xs))

    data = export.export(jax.jit(flat))(*leaves).serialize()
    try:
        folder.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(f".tmp{os.getpid()}")
        tmp.write_bytes(data)
        os.replace(tmp, path)
    except OSError:  # a read-only cache: keep the program in memory only
        pass
    # run what a later process will load, so that its numbers never differ
    return export.deserialize(data)


def call(fn: Callable, *args):
    """``fn(*args)`` through an executable compiled once per argument shape (and
    traced once per machine where the caches allow)."""
    leaves, tree = jax.tree_util.tree_flatten(args)
    key = (fn, tree, tuple((x.shape, x.dtype, x.sharding) for x in leaves))
    got = _EXECUTABLES.get(key)
    if got is None:
        t0 = time.perf_counter()
        desc, folder = _DESCRIPTIONS.get(fn), _folder()
        if desc is None or folder is None:
            got = (fn.lower(*args).compile(), False)
        else:
            exp = _exported(fn, desc, folder, leaves, tree)
            got = (jax.jit(exp.call).lower(*leaves).compile(), True)
        _COMPILE_SECONDS[0] += time.perf_counter() - t0
        _EXECUTABLES[key] = got
        while len(_EXECUTABLES) > _MAX_EXECUTABLES:
            _EXECUTABLES.popitem(last=False)
    else:
        _EXECUTABLES.move_to_end(key)
    exe, flat = got
    return exe(*leaves) if flat else exe(*args)
