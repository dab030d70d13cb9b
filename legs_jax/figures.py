"""``python -m legs_jax.figures``: regenerate the tables, figures and REPORT.md
from saved results (:mod:`legs_jax.report.figures`)."""

if __name__ == "__main__":
    from legs_jax.report.figures import main

    raise SystemExit(main())
