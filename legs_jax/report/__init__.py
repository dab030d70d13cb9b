"""Tables, figures and the report from saved results: the numbers (``analysis``,
pure functions of the result tables), the driver, readers and plotting helpers
(``figures``), tables and the report's text (``document``) and the drawing of
objects (``render``). What each experiment makes is in its own folder,
``experiments/<name>/analysis.py``.
"""
