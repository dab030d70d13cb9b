"""The session folder: what is written, when, and how it is read back.

Layout of a session folder::

    session.json      the configuration, written once (atomically)
    poses/NNN.npz     each pose's cached cloud and grasp reservoir, written once
                      (atomically) before the log names it
    log.jsonl         one JSON record per observation and per outcome, appended
                      and flushed to disk (fsync) before ``observe``/``tell``
                      return
    lock              held (flock) by the one process that has the session open

Every log record carries its sequence number and a CRC-32 of its contents, and
every pose file's SHA-256 is in the record that introduces it. The method's
posteriors, the drop counts and the recommendations are recomputed on opening by
replaying the logged outcomes through the same update functions (no random draw
is involved in an update, so the replay is exact). A ``kill -9`` can only tear
the record being written; that record's call had not returned, so a torn last
line is dropped (with a warning). Any other damage (a bad checksum inside the
log, a sequence gap, a missing or altered pose file, a folder of another kind)
is refused with a message naming the file.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import os
import warnings
import zlib
from pathlib import Path

import numpy as np

from legs_jax.online.errors import StateError

__all__ = ["FORMAT", "VERSION", "Store"]

FORMAT = "legs_jax.online.session"
VERSION = 1


def _fsync_dir(path: Path) -> None:
    with contextlib.suppress(OSError):
        fd = os.open(path, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)


def atomic_write(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` via a temporary file, fsync and rename."""
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "wb") as fh:
        fh.write(data)
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)
    _fsync_dir(path.parent)


def _crc(record: dict) -> str:
    body = json.dumps(record, sort_keys=True, separators=(",", ":"))
    return f"{zlib.crc32(body.encode()):08x}"


class Store:
    """A session folder opened by this process (see the module docstring)."""

    def __init__(self, folder: Path, config: dict, records: list[dict]):
        self.folder = folder
        self.config = config
        self.records = records
        self._log = open(folder / "log.jsonl", "ab")  # noqa: SIM115
        self._lock = None

    # ------------------------------------------------------------- create/open
    @classmethod
    def create(cls, folder, config: dict) -> Store:
        folder = Path(folder)
        if (folder / "session.json").exists() or (folder / "log.jsonl").exists():
            raise StateError(
                f"{folder} already holds a session; resume it, or choose another folder"
            )
        if folder.exists() and not folder.is_dir():
            raise StateError(f"{folder} is a file, not a folder")
        folder.mkdir(parents=True, exist_ok=True)
        (folder / "poses").mkdir(exist_ok=True)
        lock = cls._take_lock(folder)
        full = {"format": FORMAT, "version": VERSION, **config}
        atomic_write(
            folder / "session.json", (json.dumps(full, indent=1) + "\n").encode()
        )
        (folder / "log.jsonl").touch()
        _fsync_dir(folder)
        st = cls(folder, full, [])
        st._lock = lock
        return st

    @classmethod
    def open(cls, folder) -> Store:
        folder = Path(folder)
        path = folder / "session.json"
        if not path.is_file():
            raise StateError(f"{folder} holds no session (no session.json)")
        try:
            config = json.loads(path.read_text())
        except (OSError, UnicodeDecodeError, json.JSONDecodeError) as e:
            raise StateError(f"{path} is not a session file: {e}") from None
        if not isinstance(config, dict) or config.get("format") != FORMAT:
            raise StateError(
                f"{path} is not a legs_jax online session (format "
                f"{config.get('format') if isinstance(config, dict) else None!r})"
            )
        if config.get("version") != VERSION:
            raise StateError(
                f"{path} has session format version {config.get('version')!r}; this "
                f"code reads version {VERSION}"
            )
        lock = cls._take_lock(folder)
        records = cls._read_log(folder / "log.jsonl")
        st = cls(folder, config, records)
        st._lock = lock
        return st

    @staticmethod
    def _take_lock(folder: Path):
        import fcntl

        fh = open(folder / "lock", "a")  # noqa: SIM115
        try:
            fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            fh.close()
            raise StateError(
                f"{folder} is open in another process; one process drives a session"
            ) from None
        return fh

    @staticmethod
    def _read_log(path: Path) -> list[dict]:
        if not path.is_file():
            raise StateError(f"{path} is missing")
        raw = path.read_bytes()
        lines = raw.split(b"\n")
        tail = lines.pop()  # after the last newline: empty, or a torn record
        records = []
        for i, line in enumerate(lines):
            rec = _parse(line)
            where = f"{path} line {i + 1}"
            if rec is None:
                raise StateError(f"{where} is corrupt (bad JSON or checksum)")
            if rec.get("seq") != i:
                raise StateError(
                    f"{where}: sequence number {rec.get('seq')}, expected {i}"
                )
            records.append(rec)
        if tail:
            if _parse(tail) is not None:
                records.append(_parse(tail))  # complete but for its newline
            else:
                warnings.warn(
                    f"{path}: dropped a torn last record (its call never returned)",
                    stacklevel=3,
                )
            with open(path, "r+b") as fh:  # cut the torn bytes off
                fh.truncate(len(raw) - len(tail))
                if _parse(tail) is not None:
                    fh.seek(0, 2)
                    fh.write(b"\n")
                fh.flush()
                os.fsync(fh.fileno())
        return records

    # ------------------------------------------------------------------ writes
    def append(self, record: dict) -> dict:
        """Append ``record`` (with seq and crc) and fsync; returns it."""
        rec = {**record, "seq": len(self.records)}
        rec["crc"] = _crc(rec)
        line = json.dumps(rec, sort_keys=True, separators=(",", ":")) + "\n"
        self._log.write(line.encode())
        self._log.flush()
        os.fsync(self._log.fileno())
        self.records.append(rec)
        return rec

    def write_pose(self, index: int, arrays: dict[str, np.ndarray]) -> tuple[str, str]:
        """Write pose ``index``'s arrays atomically; (file name, sha256)."""
        buf = io.BytesIO()
        np.savez(buf, **arrays)
        data = buf.getvalue()
        name = f"poses/{index:03d}.npz"
        atomic_write(self.folder / name, data)
        return name, hashlib.sha256(data).hexdigest()

    def read_pose(self, name: str, sha256: str) -> dict[str, np.ndarray]:
        path = self.folder / name
        try:
            data = path.read_bytes()
        except OSError:
            raise StateError(f"{path} is missing") from None
        if hashlib.sha256(data).hexdigest() != sha256:
            raise StateError(f"{path} does not match its checksum in the log")
        with np.load(io.BytesIO(data)) as z:
            return {k: z[k] for k in z.files}

    def close(self) -> None:
        self._log.close()
        if self._lock is not None:
            self._lock.close()
            self._lock = None


def _parse(line: bytes) -> dict | None:
    try:
        rec = json.loads(line)
    except (UnicodeDecodeError, json.JSONDecodeError):
        return None
    if not isinstance(rec, dict) or "crc" not in rec:
        return None
    crc = rec.pop("crc")
    if crc != _crc(rec):
        return None
    rec["crc"] = crc
    return rec
