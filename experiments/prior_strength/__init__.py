"""The ``prior_strength`` experiment: its declaration (``sweep.py``) and analysis."""
