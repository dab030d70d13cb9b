"""The ``prior_synthetic`` experiment: its declaration (``sweep.py``)."""
