"""The ``early_stopping`` experiment: its declaration (``sweep.py``) and analysis."""
