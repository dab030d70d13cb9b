"""The report's discussion states what Table I shows by computing it: which rows
the proposed method is below or above, which differences are within the
combined standard error, and how the lowest row compares with the oracle row."""

from __future__ import annotations

import pandas as pd

from experiments.main import prose


def _t1(values):
    rows = [("dexnet_adv", m, "", 13, mean, se) for m, (mean, se) in values.items()]
    return pd.DataFrame(
        rows, columns=["set", "method", "variant", "n_objects", "mean", "se"]
    )


_ROWS = ("dexnet", "tql", "borges_100", "k100_ub", "borges_2000", "legs_no_as", "legs")
_MEANS = (0.50, 0.30, 0.09, 0.05, 0.20, 0.21, 0.10)
BASE = {
    m: (v, 0.01 if m == "k100_ub" else 0.02) for m, v in zip(_ROWS, _MEANS, strict=True)
}


def test_comparisons_follow_the_numbers():
    (text, _) = prose._prior_comparisons(_t1(BASE))
    assert text.startswith("On Dex-Net Adversarial, LEGS (0.100) is below ")
    assert "above BORGES (K_s=100) (0.090)" in text
    assert "within the combined standard error of BORGES (K_s=100))" in text
    assert "lowest compared row, BORGES (K_s=100) (0.090), is above" in text
    assert "In the paper the lowest row here is BORGES (K_s=2000) and LEGS" in text
    # other numbers, other sentences
    moved = dict(BASE, legs=(0.04, 0.001), borges_100=(0.30, 0.001))
    (text, _) = prose._prior_comparisons(_t1(moved))
    assert "; above" not in text and "is below Dex-Net" in text
    assert "every difference outside the combined standard error" in text
    assert "lowest compared row, LEGS (0.040), is not above" in text


def test_our_method_is_set_against_the_lowest_other_row():
    """Means, their combined standard error and the paired difference, worked
    out by hand for three objects; the oracle row (lower still) is left out."""
    from experiments.main import prose

    rows = []
    for method, gaps in {
        "pooled_ucb": (0.10, 0.20, 0.30),
        "bayes_ucb_100": (0.12, 0.21, 0.33),
        "legs": (0.20, 0.30, 0.40),
        "k100_ub": (0.01, 0.02, 0.03),
    }.items():
        for obj, g in zip("abc", gaps, strict=True):
            rows.append(
                dict(set="s", object=obj, method=method, variant="", gap_mean=g)
            )
    (line,) = prose._ours_lines(pd.DataFrame(rows), "s")
    # ours 0.200 ± 0.1/√3; Bayes-UCB 0.220 ± 0.10536/√3: combined 0.08386
    assert "0.200 ± 0.058, the lowest of all rows but the oracle" in line
    assert "(Bayes-UCB (K_s=100), 0.220) -0.0200" in line
    assert "0.2 combined standard errors of the two means (0.0839)" in line
    # paired differences -0.02, -0.01, -0.03: mean -0.02, SE 0.01/√3
    assert "paired over the 3 objects -0.0200 ± 0.0058" in line
    assert "lower on 3 of 3 objects" in line


def test_wins_among_all_rows_name_ours_and_the_next():
    """The win counts among every row: ours and the row with the next most wins
    (from a count table made by hand, two sets, one without our method)."""
    from experiments.main import prose

    w = pd.DataFrame(
        [
            ("s", "legs", 1, 4, 4),
            ("s", "bayes_ucb_100", 2, 4, 4),
            ("s", "pooled_ucb", 3, 4, 4),
            ("t", "legs", 1, 2, 2),
        ],
        columns=["set", "method", "wins", "n_objects", "n_total"],
    )
    (line,) = prose._wins_all_lines(w, "s")
    assert "Pooled Bayes-UCB (ours) wins 3 of 4 objects" in line
    assert "the next most Bayes-UCB (K_s=100) 2." in line
    assert prose._wins_all_lines(w, "t") == []
    assert prose._wins_all_lines(None, "s") == []
