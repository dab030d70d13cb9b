"""precompute: meshes -> problem files.

``python -m precompute --help`` builds problem files; ``python -m precompute report``
summarises them. The sweep calls :func:`ensure`, which builds missing or out-of-date
problem files on demand. NumPy, trimesh and Embree; JAX (flax, optax) only for the
learned prior (``train-prior`` and ``--prior learned``).
"""

from . import catalog
from .build import CODE_VERSION, BuildParams, build_problem, out_of_date
from .errors import PrecomputeError
from .runner import ensure

__all__ = [
    "CODE_VERSION",
    "BuildParams",
    "PrecomputeError",
    "build_problem",
    "catalog",
    "ensure",
    "out_of_date",
]
