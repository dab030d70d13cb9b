"""LEGS on a robot: an online session over depth images (see README, "On a robot").

- :class:`Session`: ``observe`` → ``ask`` → ``tell``, ``bound``; persisted in a
  folder after every call and resumed by :meth:`Session.open`.
- :mod:`legs_jax.online.recognition`: stable poses from point clouds.
- :mod:`legs_jax.online.sampler`: antipodal grasps on a depth image, the prior.
- :mod:`legs_jax.online.robot`: the simulated robot.
- ``python -m legs_jax.online``: ``serve`` (JSON lines), ``simulate``,
  ``recognition-table``, ``bench``.
"""

from legs_jax.online.camera import Intrinsics, default_camera_pose
from legs_jax.online.errors import InputError, OrderError, StateError
from legs_jax.online.session import Session

__all__ = [
    "InputError",
    "Intrinsics",
    "OrderError",
    "Session",
    "StateError",
    "default_camera_pose",
]
