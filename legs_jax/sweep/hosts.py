"""Devices and hosts: CPU device flags, the compilation cache, the local devices
and ``jax.distributed`` across hosts."""

from __future__ import annotations

import argparse
import dataclasses
import os
from typing import Any

from legs_jax import results as res
from legs_jax.sweep.plan import MAX_DEFAULT_HOST_DEVICES, SweepError
from legs_jax.sweep.store import _exp_dir


def _set_device_flags(n: int | None) -> None:
    """Ask XLA for host (CPU) devices: ``n``, or by default one per core (at most
    8), since separate CPU devices run rollouts in parallel. It only matters on a
    CPU-only machine, takes effect only before JAX starts, and an explicit
    ``--xla_force_host_platform_device_count`` in XLA_FLAGS wins."""
    if n is None:
        n = min(os.cpu_count() or 1, MAX_DEFAULT_HOST_DEVICES)
    flags = os.environ.get("XLA_FLAGS", "")
    if n < 2 or "xla_force_host_platform_device_count" in flags:
        return
    os.environ["XLA_FLAGS"] = (
        flags + f" --xla_force_host_platform_device_count={n}"
    ).strip()


# ======================================================================== devices
def _devices(n: int | None):
    import jax

    local = jax.local_devices()
    if n is not None and n > len(local):
        raise SweepError(
            f"--devices {n}: only {len(local)} local device(s) "
            f"({local[0].platform}) are available"
        )
    return local[: n or len(local)]


def _device_info(devices) -> dict[str, Any]:
    """The devices, and the XLA options the simulation programs are compiled with
    on them (512-bit vectors on a CPU with AVX-512: they move our bound's last
    bits)."""
    from legs_jax.runtime.programs import cpu_vector_options  # jax started

    return {
        "platform": devices[0].platform,
        "kind": devices[0].device_kind,
        "count": len(devices),
        "xla_options": cpu_vector_options(devices),
    }


# ============================================================================ main
@dataclasses.dataclass
class _Dist:
    num_processes: int = 1
    process_id: int = 0

    @property
    def leader(self) -> bool:
        return self.process_id == 0


def _init_distributed(a: argparse.Namespace) -> _Dist:
    if a.coordinator is None:
        return _Dist()
    import jax

    jax.distributed.initialize(
        coordinator_address=a.coordinator,
        num_processes=a.num_processes,
        process_id=a.process_id,
    )
    return _Dist(a.num_processes, a.process_id)


def _barrier(dist: _Dist, name: str) -> None:
    """All processes meet here (``jax.experimental.multihost_utils``, JAX's public
    barrier). Callers make the wait short: see :func:`_wait_for_chunks`."""
    if dist.num_processes == 1:
        return
    from jax.experimental import multihost_utils

    multihost_utils.sync_global_devices(name)


def _wait_for_chunks(dist: _Dist, plans, out, poll_s: float = 2.0) -> None:
    """Wait, on the shared output folder, until every chunk of every plan is
    finished (whichever process computed it), so that the barrier after it is a
    short one however unequal the processes' shares of the work were."""
    import time

    if dist.num_processes == 1:
        return
    while True:
        left = [
            c.id
            for p in plans
            for c in p.chunks
            if not res.chunk_done(_exp_dir(out, p.name) / "chunks", c.id)
        ]
        if not left:
            return
        time.sleep(poll_s)
