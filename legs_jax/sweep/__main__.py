"""``python -m legs_jax.sweep``: see :mod:`legs_jax.sweep`."""

import sys

from legs_jax.sweep.cli import main

sys.exit(main())
