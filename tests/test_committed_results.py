"""The committed tables are what the committed results give: regenerating them from
``results/`` (without rerunning anything) reproduces every committed table file
byte for byte."""

from __future__ import annotations

import os
from pathlib import Path

os.environ.setdefault("MPLBACKEND", "Agg")

import pytest

import experiments
from legs_jax.report import figures

REPORTED = experiments.for_report()

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "results"
TABLES = RESULTS / "tables"


def _committed_tables() -> list[Path]:
    if not TABLES.is_dir():
        return []
    return sorted(p for p in TABLES.iterdir() if p.suffix in (".md", ".tex", ".csv"))


@pytest.mark.skipif(
    not (RESULTS / "main" / "runs.parquet").is_file() or not _committed_tables(),
    reason="no committed results in this checkout",
)
def test_committed_tables_regenerate_exactly(tmp_path):
    out = tmp_path / "out"
    figures.generate(RESULTS, out, ROOT / "data", experiments=REPORTED, progress=False)
    committed = _committed_tables()
    assert len(committed) >= 8
    for path in committed:
        fresh = out / "tables" / path.name
        assert fresh.is_file(), f"{path.name} was not regenerated"
        assert fresh.read_bytes() == path.read_bytes(), path.name
