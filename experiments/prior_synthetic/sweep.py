"""Table I's Dex-Net rows with the synthetic prior (the stand-in made from p,
``precompute.prior``), beside the main experiment's rows with the learned prior.

The same arms, sizes and seeds as ``main``; only the prior q of the problem files
differs (``PRIOR``: they are built with ``--prior synthetic`` into the problems
folder's ``prior-synthetic`` subfolder).
"""

from experiments.main import sweep as _main

NAME = "prior_synthetic"
DESCRIPTION = "Table I on the Dex-Net objects with the synthetic prior"
ORDER = 6  # place in --all, the figures and the report

OBJECTS = ("dexnet_adv",)
# Table I's arms of main (not its extra variant and rows: the comparison is of
# the prior, on the paper's seven methods).
ARMS = tuple(a for a in _main.ARMS if a[0] in _main.TABLE_ORDER and not a[1])
CHECK_METHODS = _main.CHECK_METHODS
SMOKE_OBJECTS = ("bar_clamp",)

# The prior the problem files carry (precompute --prior).
PRIOR = "synthetic"
