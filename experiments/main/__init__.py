"""The ``main`` experiment: its declaration (``sweep.py``) and analysis."""
