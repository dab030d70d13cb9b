"""The ``confidence`` experiment: its declaration (``sweep.py``) and analysis."""
