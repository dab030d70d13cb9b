"""The committed tables are what the committed results give: regenerating them from
``results/`` (without rerunning anything) reproduces every committed table file
byte for byte; the runs that one experiment copies from another are the other's."""

from __future__ import annotations

import json
import os
from pathlib import Path

os.environ.setdefault("MPLBACKEND", "Agg")

import pandas as pd
import pytest

import experiments
from legs_jax import results
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


# What a run gave (the package's run results but the horizon, which names it), and
# the columns that name a run (its configuration and seed; not the experiment).
_RUN_OUTCOME = [c for c in results._RUN_RESULTS if c != "horizon"]
_RUN_KEY = [
    c for c in results._run_columns() if c not in _RUN_OUTCOME and c != "experiment"
]


def _copied_arms(experiment: str) -> list[str]:
    """Arms of ``experiment`` whose every chunk was copied from ``main``."""
    manifest = json.loads((RESULTS / experiment / "manifest.json").read_text())
    copied: dict[str, bool] = {}
    for chunk_id, chunk in manifest["chunks"].items():
        arm = chunk_id.split("__")[0]
        sources = chunk.get("reused_from") or []
        from_main = bool(sources) and all(s.startswith("main/") for s in sources)
        copied[arm] = copied.get(arm, True) and from_main
    return sorted(arm for arm, ok in copied.items() if ok)


@pytest.mark.skipif(
    not (RESULTS / "main" / "runs.parquet").is_file(),
    reason="no committed results in this checkout",
)
@pytest.mark.parametrize("experiment", ["case_study", "early_stopping"])
def test_rows_copied_from_main_are_mains_rows(experiment):
    """An experiment that repeats runs of ``main`` copies their chunks; when one of
    ``main``'s rows is recomputed, the copies must follow it (a stale copy would
    make the case study disagree with Table I for the same seeds)."""
    arms = _copied_arms(experiment)
    assert arms, f"{experiment} copies no arm of main"
    main = pd.read_parquet(RESULTS / "main" / "runs.parquet")
    runs = pd.read_parquet(RESULTS / experiment / "runs.parquet")
    dotted = runs["method"] + "." + runs["variant"]
    arm = runs["method"].where(runs["variant"] == "", dotted)
    copied = runs[arm.isin(arms)]
    assert len(copied) > 0
    both = copied.merge(main, on=_RUN_KEY, how="left", suffixes=("", "_main"))
    assert len(both) == len(copied), "a copied run matches several of main's"
    missing = both["final_gap_main"].isna()
    assert not missing.any(), f"{int(missing.sum())} copied runs are not in main"
    for col in _RUN_OUTCOME:
        differ = both[col].to_numpy() != both[col + "_main"].to_numpy()
        bad = both.loc[differ, ["object", "method", "trial", "rollout"]]
        assert not differ.any(), f"{col} differs from main's in {len(bad)} runs:\n{bad}"
