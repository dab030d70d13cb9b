"""``python -m legs_jax.figures``: the tables, figures and REPORT.md of a results
folder (:func:`legs_jax.report.figures.generate`), with the paper's experiments
(``experiments/``) as the analyses to run."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

import experiments
from legs_jax.report.figures import MissingResults, generate

_PROG = "python -m legs_jax.figures"
_DESCRIPTION = (
    "Regenerate the tables, figures and REPORT.md of a results folder from its "
    "saved sweep results (never reruns a sweep): for the paper's experiments "
    "Table I with win counts, per-object gaps, Fig. 3 case study, Fig. 4 early "
    "stopping, the two appendix tables, the active-set evolution of one LEGS "
    "rollout, and REPORT.md with every number beside the paper's; for a folder "
    "of your own (a subset of objects or methods, your problems or methods) what "
    "its results allow, and for a --grid sweep the final gap against each grid "
    "axis (a table and a figure). Experiments without results are listed as not "
    "run; an output whose results are missing is skipped with a message naming "
    "the missing file (exit status 1)."
)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog=_PROG, description=_DESCRIPTION)
    p.add_argument(
        "--results",
        default="results",
        metavar="DIR",
        help="folder holding <experiment>/runs.parquet etc. (default: results)",
    )
    p.add_argument(
        "--out",
        default=None,
        metavar="DIR",
        help="write tables/, figures/ and REPORT.md here (default: the results folder)",
    )
    p.add_argument(
        "--data",
        default="data",
        metavar="DIR",
        help="folder with meshes/<set>/<name>.obj and problems/<set>/<name>.npz "
        "for drawing objects (default: data)",
    )
    p.add_argument(
        "--case-objects",
        nargs="+",
        action="extend",
        default=None,
        metavar="NAME",
        help="objects of Fig. 3 (default: the case_study experiment's objects)",
    )
    p.add_argument(
        "--active-object",
        default=None,
        metavar="NAME",
        help="object whose LEGS active set is drawn (default: the case-study "
        "object whose active set changes most)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress bar or listing")
    p.add_argument(
        "--debug",
        action="store_true",
        help="stop with a traceback when an output fails unexpectedly",
    )
    return p


def main(argv: Sequence[str] | None = None) -> int:
    a = build_parser().parse_args(argv)
    try:
        written, problems = generate(
            a.results,
            a.out,
            a.data,
            experiments=experiments.for_report(),
            case_objects=a.case_objects,
            active_object=a.active_object,
            progress=not a.quiet,
            debug=a.debug,
        )
    except MissingResults as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    if not a.quiet:
        for p in written:
            print(f"wrote {p}")
    for msg in problems:
        print(f"error: {msg}", file=sys.stderr)
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())
