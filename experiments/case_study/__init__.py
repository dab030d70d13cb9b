"""The ``case_study`` experiment: its declaration (``sweep.py``) and analysis."""
