"""The constants that the engine, the methods and the NumPy reference
share, declared once (this module imports nothing, so the NumPy reference stays
free of JAX)."""

__all__ = [
    "DELTA_STOP",
    "NUM_DIRICHLET_SAMPLES",
    "NUM_EB_SAMPLES",
    "Q_CLIP",
    "TOP_FIXED",
]

#: q is clipped to this range inside the Beta parameters.
Q_CLIP = (0.01, 0.99)
#: Candidate set of BORGES (K=100) and of the K100 upper bound.
TOP_FIXED = 100
#: Quantile of the Dirichlet stopping bound (independent of LEGS's δ).
DELTA_STOP = 0.05
#: M, the Dirichlet samples of one check.
NUM_DIRICHLET_SAMPLES = 3000
#: M' of our stopping bound: its δ-quantile is taken over the first M' of the M
#: Dirichlet samples, each with its own draw of the recommended grasps' p (fewer
#: samples, so that our check alone costs less than the paper's; the Monte Carlo
#: error of a 5 % quantile of 1000 samples is a small share of the posterior's
#: spread).
NUM_EB_SAMPLES = 1000
