"""The report's plotting and file helpers: matplotlib set up alike for every
figure (:func:`pyplot`), PNGs saved without a timestamp so that regenerated
figures are byte-identical (:func:`save_figure`), and CSV tables
(:func:`write_csv`)."""

from __future__ import annotations

from pathlib import Path

import pandas as pd

from legs_jax.report import document as rp

__all__ = ["pyplot", "save_figure", "write_csv"]

_PNG_META = {"Software": None}
_DPI = 150


def pyplot():
    import matplotlib

    if matplotlib.get_backend().lower() not in ("agg", "pdf", "svg", "cairo"):
        try:
            matplotlib.use("Agg")
        except Exception:  # noqa: BLE001 - keep the current backend
            pass
    import matplotlib.pyplot as plt

    plt.rcParams.update(
        {
            "font.size": 9,
            "axes.titlesize": 10,
            "axes.labelsize": 9,
            "legend.fontsize": 8.5,
            "xtick.labelsize": 8,
            "ytick.labelsize": 8,
            "axes.spines.top": False,
            "axes.spines.right": False,
        }
    )
    return plt


def save_figure(fig, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=_DPI, metadata=_PNG_META, facecolor="white")
    import matplotlib.pyplot as plt

    plt.close(fig)
    return path


def write_csv(df: pd.DataFrame, path: Path) -> Path:
    rp.write_text(path, rp.to_csv(df))
    return path
