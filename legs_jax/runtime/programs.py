"""Compiled programs of the engine, each made once per process, and traced and
compiled once per machine.

:func:`call` runs a jitted function through an executable compiled ahead of time
for its argument shapes (so that compilation is timed apart from running,
:func:`compile_seconds`). Where JAX's persistent compilation cache is on
(:func:`legs_jax._jax_cache.compile_cache`) and the function was described with
:func:`describe`, two things are kept in the cache folder's ``legs_jax-exported/``:

- the traced program (``jax.export``, ``<key>.bin``): a later process deserialises
  it instead of tracing and lowering the Python code again (LEGS took 1.5-3 s to
  trace on a 2-core machine);
- its executable, compiled for this processor and these devices
  (``<key>-<machine>-d<device ids>.exe``, ``jax.experimental.serialize_executable``):
  a later process loads it and neither lowers nor compiles (lowering alone cost a
  small job 0.3 s, a fifth of its time). These executables are compiled apart from
  JAX's persistent cache (jaxlib 0.10 cannot serialise an executable loaded from
  there again), so they stand in for it.

Every call goes through the exported program whenever the cache is on, the first
one included, so the numbers never depend on whether a program was traced here or
loaded; a test checks that they equal those of the plain jitted function, and that
a second process traces and compiles nothing.

A kept program is found by the SHA-256 of: the source of every module of
``legs_jax``, the versions of jax, jaxlib, NumPy and SciPy, the function's
description (method, static configuration, devices, XLA options) and its
arguments' shapes, types and shardings; its executable also by the processor
(model and instruction set flags) and the XLA backend's version. Only the
registered methods (all their functions in ``legs_jax``) are kept: a user's method
may depend on code outside the package, so it is traced anew by each process.
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
_OPTIONS: dict[Any, tuple] = {}
_FOLDER = "legs_jax-exported"
# The choice of the simulation programs' vector width on CPU (see cpu_vector_options).
VECTOR_WIDTH_ENV = "LEGS_JAX_CPU_VECTOR_WIDTH"


def compile_seconds() -> float:
    """Seconds this process has spent tracing, lowering and compiling (or loading
    from the caches) the programs run through :func:`call`."""
    return _COMPILE_SECONDS[0]


def describe(
    fn: Callable,
    name: str | None,
    *parts: Any,
    compiler_options: dict[str, Any] | None = None,
) -> Callable:
    """Record a stable description of the jitted ``fn`` (a name and its static
    facts), which lets :func:`call` keep its traced program on disk; returns
    ``fn``. A name of None keeps it off disk. ``compiler_options`` (XLA's, those
    ``fn`` was jitted with) are used again where :func:`call` compiles the kept
    program, and are part of its description."""
    options = tuple(sorted((compiler_options or {}).items()))
    if options:
        _OPTIONS[fn] = options
    if name is not None:
        _DESCRIPTIONS[fn] = repr((name, *parts, *((options,) if options else ())))
    return fn


def cpu_vector_options(devices=None) -> dict[str, Any]:
    """XLA options for the engine's simulation programs: 512-bit vectors on a CPU
    with AVX-512, none elsewhere.

    XLA's CPU backend prefers 256-bit vectors even where the processor has 512-bit
    ones; the exact Beta sampler, most of a Thompson step, runs about 1.25 times as
    fast with 512, with the same bits. Every run and curve measured was the same
    bits either way; our bound, computed inside the simulation programs, moves by
    float32 rounding (its fit sums in another order). The Dirichlet checks
    (:func:`legs_jax.runtime.rollouts.compiled_checks`) keep XLA's default, so the
    paper's bound keeps the bits of earlier results made on the same processor.
    ``LEGS_JAX_CPU_VECTOR_WIDTH=256`` (or ``512``) sets the width instead.
    """
    platform = devices[0].platform if devices else jax.default_backend()
    if platform != "cpu":
        return {}
    choice = os.environ.get(VECTOR_WIDTH_ENV, "").strip()
    if choice == "":
        from legs_jax._machine import machine

        wide = machine()["isa"] == "AVX-512"
    elif choice in ("256", "512"):
        wide = choice == "512"
    else:
        from legs_jax.errors import ConfigError

        raise ConfigError(
            f"{VECTOR_WIDTH_ENV} must be 256 or 512 (or unset: 512 on a CPU with"
            f" AVX-512, else 256), got {choice!r}"
        )
    return {"xla_cpu_prefer_vector_width": 512} if wide else {}


def method_fingerprint(method: Any) -> str | None:
    """The name of a registered method whose functions all live in ``legs_jax``
    (None for any other: it is not kept on disk)."""
    values = [getattr(method, f.name) for f in dataclasses.fields(method)]
    values += [getattr(method.card, f.name) for f in dataclasses.fields(method.card)]
    for v in values:
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
    root = Path(__file__).resolve().parents[1]  # the whole package
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


def _key(desc: str, leaves, tree) -> str:
    """The name of a kept program: the code, the description, the arguments."""
    return hashlib.sha256(
        "\n".join(
            [
                _code_fingerprint(),
                desc,
                str(tree),
                repr([(x.shape, str(x.dtype), repr(x.sharding)) for x in leaves]),
            ]
        ).encode()
    ).hexdigest()


def _write(path: Path, data: bytes) -> None:
    """Write atomically; a read-only cache keeps the program in memory only."""
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(f".tmp{os.getpid()}")
        tmp.write_bytes(data)
        os.replace(tmp, path)
    except OSError:
        pass


def _exported(fn: Callable, key: str, folder: Path, leaves, tree):
    """The exported program of ``fn`` flattened over its argument leaves, read
    from ``folder`` or made and written there."""
    from jax import export

    path = folder / f"{key}.bin"
    if path.is_file():
        try:
            return export.deserialize(bytearray(path.read_bytes()))
        except Exception:  # noqa: BLE001 - a damaged file is made again
            pass

    # Exported, the program is traced inside another jit, where a nested jit may
    # not carry compiler options: the same function jitted without them.
    plain = jax.jit(fn.__wrapped__) if fn in _OPTIONS else fn

    def flat(*xs):
        return plain(*jax.tree_util.tree_unflatten(tree, xs))

    data = export.export(jax.jit(flat))(*leaves).serialize()
    _write(path, data)
    # run what a later process will load, so that its numbers never differ
    return export.deserialize(data)


@functools.lru_cache(maxsize=1)
def _machine_fingerprint() -> str:
    """The processor and the XLA backend an executable was compiled for (XLA's
    CPU code uses the instruction-set extensions of the processor it ran on)."""
    import platform

    dev = jax.devices()[0]
    parts = [dev.platform, dev.device_kind, dev.client.platform_version]
    parts.append(platform.machine())
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as f:
            info = f.read().split("\n\n")[0]
        parts += [
            line for line in info.splitlines()
            if line.startswith(("model name", "flags", "Features", "CPU part"))
        ]  # fmt: skip
    except OSError:
        parts.append(platform.processor())
    return hashlib.sha256("\n".join(parts).encode()).hexdigest()[:16]


def _execution_devices(leaves) -> tuple | None:
    """The devices a program over these (committed) arguments runs on, in the
    order of its device assignment; None where that cannot be told."""
    from jax.sharding import NamedSharding, SingleDeviceSharding

    for x in leaves:
        s = getattr(x, "sharding", None)
        if isinstance(s, NamedSharding):
            return tuple(s.mesh.devices.flat)
        if isinstance(s, SingleDeviceSharding):
            return tuple(s.device_set)
    return None


def _fresh_compile(lowered, options=None):
    """Compile without JAX's persistent cache: an executable loaded from there
    cannot be serialised again (jaxlib 0.10 drops its functions), so the kept
    executables are made from fresh compiles, and then stand in for that cache.

    JAX 0.10 documents no per-call way to bypass that cache (``compile()`` takes
    XLA options only, and ``jax_enable_compilation_cache`` is not one of JAX's
    public context managers), so the flag is turned off around this one compile
    and restored, with the cache's state, in ``finally`` whatever happens.

    Tried instead: compiling with the cache on and keeping the executable only
    when it loads back. An executable that JAX took from its cache serialises,
    loads and runs again in the same process, but a later process fails when it
    runs it ("Function wrapped_broadcast.5 not found"), so no check inside one
    process can tell the two apart."""
    from jax.experimental.compilation_cache import compilation_cache

    was = jax.config.jax_enable_compilation_cache
    jax.config.update("jax_enable_compilation_cache", False)
    compilation_cache.reset_cache()
    try:
        return lowered.compile(options)
    finally:
        jax.config.update("jax_enable_compilation_cache", was)
        compilation_cache.reset_cache()


def _executable(fn: Callable, desc: str, folder: Path, leaves, tree):
    """The compiled program of ``fn`` over the flat ``leaves``: its kept executable
    when this machine made one, else compiled from the kept (or new) exported
    program and kept."""
    from jax.experimental import serialize_executable

    key = _key(desc, leaves, tree)
    devices = _execution_devices(leaves)
    in_tree = jax.tree_util.tree_structure((tuple(leaves), {}))
    exe_path = None
    if devices is not None:
        ids = "-".join(str(d.id) for d in devices)
        exe_path = folder / f"{key}-{_machine_fingerprint()}-d{ids}.exe"
    exp = _exported(fn, key, folder, leaves, tree)  # its output tree, at least
    if exe_path is not None and exe_path.is_file():
        try:
            return serialize_executable.deserialize_and_load(
                exe_path.read_bytes(), in_tree, exp.out_tree,
                backend=devices[0].client, execution_devices=devices,
            )  # fmt: skip
        except Exception:  # noqa: BLE001 - a damaged file is made again
            pass
    lowered = jax.jit(exp.call).lower(*leaves)
    options = dict(_OPTIONS.get(fn, ())) or None
    if exe_path is None:
        return lowered.compile(options)
    compiled = _fresh_compile(lowered, options)
    try:
        data, made_tree, _ = serialize_executable.serialize(compiled)
    except (ValueError, NotImplementedError):
        return compiled
    if made_tree == in_tree:
        _write(exe_path, data)
    return compiled


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
            got = (_executable(fn, desc, folder, leaves, tree), True)
        _COMPILE_SECONDS[0] += time.perf_counter() - t0
        _EXECUTABLES[key] = got
        while len(_EXECUTABLES) > _MAX_EXECUTABLES:
            _EXECUTABLES.popitem(last=False)
    else:
        _EXECUTABLES.move_to_end(key)
    exe, flat = got
    return exe(*leaves) if flat else exe(*args)
