"""``python -m legs_jax.bench``: see :mod:`legs_jax.bench`."""

import sys

from legs_jax.bench.cli import main

sys.exit(main())
