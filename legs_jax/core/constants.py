"""The constants that the engine, the methods and the NumPy reference
share, declared once (this module imports nothing, so the NumPy reference stays
free of JAX)."""

__all__ = ["DELTA_STOP", "NUM_DIRICHLET_SAMPLES", "Q_CLIP", "TOP_FIXED"]

#: q is clipped to this range inside the Beta parameters.
Q_CLIP = (0.01, 0.99)
#: Candidate set of BORGES (K=100) and of the K100 upper bound.
TOP_FIXED = 100
#: Quantile of the Dirichlet stopping bound (independent of LEGS's δ).
DELTA_STOP = 0.05
#: M, the Dirichlet samples of one check.
NUM_DIRICHLET_SAMPLES = 3000
