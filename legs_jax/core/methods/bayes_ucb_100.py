"""Bayes-UCB (K=100): the grasp of highest posterior quantile among the fixed
top-100 grasps by prior (the candidate set of BORGES (K=100)); the index and its
NumPy twin are those of :mod:`legs_jax.core.methods.bayes_ucb_2000`."""

from legs_jax.core.methods.bayes_ucb_2000 import make

METHOD = make(
    "bayes_ucb_100",
    top=True,
    description="Bayes-UCB (K=100): highest posterior quantile over the top-100",
    label="Bayes-UCB (K_s=100)",
    short_label="BayesUCB-100",
    style=dict(color="#bcbd22", ls="--", lw=1.6),
)
