"""The JSON-lines protocol: a robot program drives a session over stdin/stdout.

One request per line on stdin, one response per line on stdout, in order::

    {"id": 1, "cmd": "observe", "depth": {"npy": "frame.npy"},
     "intrinsics": {"fx": 525, "fy": 525, "cx": 319.5, "cy": 239.5,
                    "width": 640, "height": 480}}
    {"id": 2, "cmd": "ask"}
    {"id": 3, "cmd": "tell", "success": true}   (optional "grasp": the asked id)
    {"id": 4, "cmd": "bound", "rho_min": 0.9}
    {"id": 5, "cmd": "verify", "rho_min": 0.9}   (optional "delta", default 0.05)
    {"id": 6, "cmd": "status"}
    {"id": 7, "cmd": "quit"}

A depth image is ``{"npy": PATH}`` (a ``.npy`` file of metres) or inline
``{"b64": ..., "dtype": "float32" | "float64" | "uint16", "shape": [H, W],
"scale": metres per unit}`` (little-endian, row-major; 0 or NaN: no reading).
Responses are ``{"id": ..., "ok": true, "result": {...}}`` or ``{"id": ...,
"ok": false, "error": {"type": ..., "message": ...}}``; an error changes nothing.
A field that the command does not take is refused (:data:`FIELDS`).
The first line written is ``{"ok": true, "ready": {...}}`` once the session is
open (created, or resumed with every recorded outcome), or ``{"ok": false,
"error": {...}}`` when it cannot be opened (another process holds it, a damaged
folder), and the process exits with status 2.

Warnings (a pose without a success after
:data:`~legs_jax.online.session.NO_SUCCESS_ATTEMPTS` attempts, one pose only
after :data:`~legs_jax.online.session.ONE_POSE_STEPS` steps of recognition) are
written to stderr, one line each beginning ``warning:``, once per process; stdout
carries the responses only.

``bound`` answers both stopping bounds: the paper's ``p_lower`` (and
``p_lower_attempted``) and ours ``p_lower_ours`` (:mod:`legs_jax.core.stopping`);
with ``rho_min`` (the stopping threshold ρ_min) also ``stop`` (the paper's bound
≥ ρ_min) and ``stop_ours`` (ours ≥ ρ_min: the signal to verify, or to stop on).
``verify`` opens a verification phase (:mod:`legs_jax.core.verify`): the next asks
give the frozen recommended grasps, and each tell's result carries
``verification`` with its ``verdict``: ``certified`` (stop), ``refuted``
(exploration resumes) or none yet.
"""

from __future__ import annotations

import base64
import json
import sys
from pathlib import Path

import numpy as np

from legs_jax.errors import ConfigError
from legs_jax.online import session as session_mod
from legs_jax.online.errors import InputError, OrderError, StateError
from legs_jax.online.session import Session

__all__ = ["FIELDS", "decode_depth", "handle", "refuse", "serve"]

_DTYPES = {"float32": "<f4", "float64": "<f8", "uint16": "<u2"}

# The fields each request may carry: any other is refused (a misspelt or
# foreign field is never ignored). ``tell``'s optional ``grasp`` must be the
# pending grasp's id.
FIELDS = {
    "observe": ("depth", "intrinsics", "pose"),
    "ask": (),
    "tell": ("success", "grasp"),
    "bound": ("rho_min",),
    "verify": ("rho_min", "delta"),
    "status": (),
    "quit": (),
}


def decode_depth(spec) -> np.ndarray:
    """The depth image of a request (see the module docstring)."""
    if not isinstance(spec, dict):
        raise InputError(
            'depth must be {"npy": PATH} or {"b64": ..., "dtype", "shape"}'
        )
    if "npy" in spec:
        try:
            return np.load(Path(spec["npy"]), allow_pickle=False)
        except (OSError, ValueError) as e:
            raise InputError(f"cannot read depth file {spec['npy']!r}: {e}") from None
    if "b64" in spec:
        dt = _DTYPES.get(spec.get("dtype"))
        if dt is None:
            raise InputError(f"depth dtype must be one of {', '.join(_DTYPES)}")
        shape = spec.get("shape")
        if not (
            isinstance(shape, list)
            and len(shape) == 2
            and all(isinstance(x, int) and x > 0 for x in shape)
        ):
            raise InputError("depth shape must be [height, width]")
        try:
            raw = base64.b64decode(spec["b64"], validate=True)
        except (ValueError, TypeError):
            raise InputError("depth b64 is not valid base64") from None
        if len(raw) != shape[0] * shape[1] * np.dtype(dt).itemsize:
            raise InputError(
                f"depth b64 holds {len(raw)} bytes; {shape} of {spec['dtype']} needs "
                f"{shape[0] * shape[1] * np.dtype(dt).itemsize}"
            )
        arr = np.frombuffer(raw, dt).reshape(shape).astype(np.float64)
        scale = spec.get("scale", 1.0)
        if not isinstance(scale, (int, float)) or not scale > 0:
            raise InputError("depth scale must be a positive number (metres per unit)")
        if spec["dtype"] == "uint16":
            arr = np.where(arr == 0, np.nan, arr)
        return arr * scale
    raise InputError('depth must be {"npy": PATH} or {"b64": ..., "dtype", "shape"}')


def handle(session: Session, req) -> dict:
    """The response to one request (never raises for bad input)."""
    rid = req.get("id") if isinstance(req, dict) else None
    try:
        if not isinstance(req, dict):
            raise InputError("a request is a JSON object")
        cmd = req.get("cmd")
        if cmd in FIELDS:
            extra = sorted(set(req) - {"id", "cmd", *FIELDS[cmd]})
            if extra:
                takes = ", ".join(FIELDS[cmd]) or "no other field"
                raise InputError(
                    f"unknown field(s) {', '.join(map(repr, extra))} for {cmd} "
                    f"(it takes id, cmd and {takes}); nothing was done"
                )
        if cmd == "observe":
            if "pose" in req:
                result = session.observe(pose=req["pose"])
            else:
                result = session.observe(
                    decode_depth(req.get("depth")), req.get("intrinsics")
                )
        elif cmd == "ask":
            result = session.ask()
        elif cmd == "tell":
            if "success" not in req:
                raise InputError('tell needs "success": true or false')
            if "grasp" in req:
                pending = session.pending_grasp()
                if pending is None:
                    raise OrderError(
                        "tell without a pending ask: ask for a grasp first"
                    )
                if isinstance(req["grasp"], bool) or req["grasp"] != pending:
                    raise OrderError(
                        f"tell names grasp {req['grasp']!r}, but the pending grasp "
                        f"is {pending}; nothing was recorded"
                    )
            result = session.tell(req["success"])
        elif cmd == "bound":
            result = session.bound(req.get("rho_min"))
        elif cmd == "verify":
            if "rho_min" not in req:
                raise InputError('verify needs "rho_min", the threshold to certify')
            result = session.verify(
                req["rho_min"], req.get("delta", session_mod.DELTA_STOP)
            )
        elif cmd == "status":
            result = session.status()
        elif cmd == "quit":
            result = {"bye": True}
        else:
            raise InputError(
                f"unknown cmd {cmd!r}; one of observe, ask, tell, bound, verify, "
                "status, quit"
            )
    except (InputError, OrderError, StateError, ConfigError) as e:
        return {
            "id": rid,
            "ok": False,
            "error": {"type": type(e).__name__, "message": str(e)},
        }
    return {"id": rid, "ok": True, "result": result}


def refuse(error: Exception, stdout=None) -> int:
    """The session could not be opened (held by another process, damaged, bad
    arguments): say so as the first line, in JSON like every other answer;
    returns the exit status 2."""
    stdout = stdout or sys.stdout
    err = {"type": type(error).__name__, "message": str(error)}
    stdout.write(json.dumps({"ok": False, "error": err}) + "\n")
    stdout.flush()
    return 2


def serve(session: Session, stdin=None, stdout=None, stderr=None) -> int:
    """Answer requests until ``quit`` or the end of stdin; the session's warnings
    go to ``stderr``, after the response that made them due."""
    stdin = stdin or sys.stdin
    stdout = stdout or sys.stdout
    stderr = stderr or sys.stderr

    def send(obj) -> None:
        stdout.write(json.dumps(obj, default=_json_default) + "\n")
        stdout.flush()

    send({"ok": True, "ready": session.status()})
    for line in stdin:
        if not line.strip():
            continue
        try:
            req = json.loads(line)
        except json.JSONDecodeError as e:
            send(
                {
                    "id": None,
                    "ok": False,
                    "error": {"type": "InputError", "message": f"not JSON: {e}"},
                }
            )
            continue
        resp = handle(session, req)
        send(resp)
        for w in session.take_warnings():
            stderr.write(f"warning: {w}\n")
            stderr.flush()
        if resp["ok"] and isinstance(req, dict) and req.get("cmd") == "quit":
            break
    return 0


def _json_default(x):
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    raise TypeError(f"not JSON serialisable: {type(x).__name__}")
