"""What the ``main`` experiment makes: Table I with win counts and per-object gaps,
the problem model before and after, and the report's discussion of Table I.

The tables and the paper's numbers are in :mod:`experiments.main.tables`, the
report's text in :mod:`experiments.main.prose`; this module lists the steps and
report sections that the figures command runs, and names the public pieces.
"""

from __future__ import annotations

from experiments.main.prose import (
    discussion,
    problem_model_section,
    table_one_section,
)
from experiments.main.tables import (
    ARMS,
    PAPER_OBJECTS,
    PAPER_SETS,
    PAPER_TABLE1,
    PAPER_WINS,
    main_tables,
    per_object_table,
    problem_model_context,
    table_one_table,
    wins_table,
)
from legs_jax.report.figures import Run

__all__ = [
    "ARMS",
    "PAPER_OBJECTS",
    "PAPER_SETS",
    "PAPER_TABLE1",
    "PAPER_WINS",
    "SECTIONS",
    "STEPS",
    "main_tables",
    "per_object_table",
    "problem_model_context",
    "table_one_table",
    "wins_table",
]


# ====================================================================== steps
def _tables_step(run: Run) -> None:
    files, run.ctx["main"] = main_tables(run.res, run.tables)
    run.written.extend(files)


def _problem_model_step(run: Run) -> None:
    run.ctx["problem_model"] = problem_model_context(run.res.root)


STEPS = (
    ("Table I, wins, per-object gaps", _tables_step),
    ("problem model before and after", _problem_model_step),
)


# (position in REPORT.md, lines): Table I first, the discussion last.
SECTIONS = (
    (10, table_one_section),
    (20, problem_model_section),
    (90, discussion),
)
