"""A sweep's outputs: the tidy table, summary statistics with quantiles, and a plot.

``samples.csv`` (or ``samples.parquet``): one row per sample with its index, grid point,
replicate, every varied input (tuple fields as ``field[i]``), status, every selected
metric, wall time and error. ``summary.csv`` / ``summary.json``: per metric (and per
grid point when there is a grid) the count of finite values, mean, standard deviation,
minimum, the 5, 25, 50, 75, 95 % quantiles and maximum over the samples that ran.
"""
from __future__ import annotations

import csv
import json
import math
from pathlib import Path

import numpy as np

from softgen.core.atomic import atomic_open, replacing, write_text

QUANTILES = (0.05, 0.25, 0.5, 0.75, 0.95)
STAT_NAMES = ("count", "mean", "std", "min", "q05", "q25", "median", "q75", "q95", "max")


def table_columns(rows: list[dict], inputs: list[str]) -> tuple[list[str], list[str]]:
    """(all columns, metric columns) in a fixed order: metrics by first appearance."""
    metrics: dict[str, None] = {}
    for r in rows:
        metrics.update(dict.fromkeys(r["metrics"]))
    cols = ["sample", "grid_point", "replicate", *inputs, "status", *metrics, "warnings",
            "wall_seconds", "error"]
    return cols, list(metrics)


def flat_row(r: dict, metric_cols: list[str]) -> dict:
    return {"sample": r["index"], "grid_point": r["grid_point"], "replicate": r["replicate"],
            **r["inputs"], "status": r["status"],
            **{m: r["metrics"].get(m, math.nan) for m in metric_cols},
            "warnings": r.get("warnings", 0), "wall_seconds": r["wall_seconds"],
            "error": r["error"]}


def write_table(path: Path, rows: list[dict], inputs: list[str], fmt: str = "csv") -> Path:
    cols, metric_cols = table_columns(rows, inputs)
    flat = [flat_row(r, metric_cols) for r in rows]
    if fmt == "parquet":
        import pyarrow as pa
        import pyarrow.parquet as pq
        target = path.with_suffix(".parquet")
        with replacing(target) as tmp:
            pq.write_table(pa.table({c: [f.get(c) for f in flat] for c in cols}), tmp)
        return target
    target = path.with_suffix(".csv")
    with atomic_open(target, "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=cols)
        w.writeheader()
        for f in flat:
            # repr of a float round-trips exactly: the table is the data, not a rounding.
            w.writerow({k: (repr(v) if isinstance(v, float) else v) for k, v in f.items()})
    return target


def stats(values: np.ndarray) -> dict[str, float]:
    v = values[np.isfinite(values)]
    if v.size == 0:
        return {"count": 0, **{k: math.nan for k in STAT_NAMES[1:]}}
    q = np.quantile(v, QUANTILES)
    return {"count": int(v.size), "mean": float(v.mean()),
            "std": float(v.std(ddof=1)) if v.size > 1 else 0.0, "min": float(v.min()),
            **dict(zip(("q05", "q25", "median", "q75", "q95"), map(float, q))),
            "max": float(v.max())}


def summarise(rows: list[dict], grid_inputs: list[str]) -> dict:
    """Status counts and per-metric statistics (overall and per grid point)."""
    _, metric_cols = table_columns(rows, [])
    ran = [r for r in rows if r["status"] == "ok"]
    counts = {s: sum(r["status"] == s for r in rows) for s in ("ok", "diverged", "error")}

    def block(sel: list[dict]) -> dict:
        return {m: stats(np.array([r["metrics"].get(m, math.nan) for r in sel], dtype=float))
                for m in metric_cols}

    out = {"samples": len(rows), "status": counts, "metrics": block(ran)}
    if grid_inputs:
        points = []
        for g in sorted({r["grid_point"] for r in rows}):
            sel = [r for r in rows if r["grid_point"] == g]
            at = {k: sel[0]["inputs"][k] for k in grid_inputs}
            points.append({"grid_point": g, "at": at, "samples": len(sel),
                           "status": {s: sum(r["status"] == s for r in sel)
                                      for s in ("ok", "diverged", "error")},
                           "metrics": block([r for r in sel if r["status"] == "ok"])})
        out["grid"] = points
    return out


def write_summary(out: Path, summary: dict) -> None:
    write_text(out / "summary.json", json.dumps(summary, indent=2, allow_nan=True) + "\n")
    with atomic_open(out / "summary.csv", "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["grid_point", "metric", *STAT_NAMES])
        blocks = [("all", summary["metrics"])] + [(p["grid_point"], p["metrics"])
                                                  for p in summary.get("grid", [])]
        for g, metrics in blocks:
            for m, s in metrics.items():
                w.writerow([g, m, *(repr(s[k]) if isinstance(s[k], float) else s[k]
                                    for k in STAT_NAMES)])


def plot(out: Path, rows: list[dict], summary: dict, grid_inputs: list[str],
         title: str, *, max_metrics: int = 8) -> Path | None:
    """``sweep.png``: histograms of the metrics, or median and 5-95 % band over a grid."""
    from matplotlib.figure import Figure
    metric_cols = list(summary["metrics"])[:max_metrics]
    if not metric_cols:
        return None
    ncol = min(4, len(metric_cols))
    nrow = math.ceil(len(metric_cols) / ncol)
    fig = Figure(figsize=(3.6 * ncol, 2.9 * nrow))
    axes = np.atleast_1d(fig.subplots(nrow, ncol)).ravel()
    one_grid = len(grid_inputs) == 1 and summary.get("grid")
    for ax, m in zip(axes, metric_cols):
        if one_grid:
            at = [p["at"][grid_inputs[0]] for p in summary["grid"]]
            numeric = all(isinstance(a, (int, float)) and not isinstance(a, bool) for a in at)
            x = np.array(at, dtype=float) if numeric else np.arange(len(at), dtype=float)
            if not numeric:                          # categories (choice of a law, ...)
                ax.set_xticks(x, [str(a) for a in at], fontsize=7)
            med = np.array([p["metrics"].get(m, {}).get("median", math.nan)
                            for p in summary["grid"]])
            lo = np.array([p["metrics"].get(m, {}).get("q05", math.nan) for p in summary["grid"]])
            hi = np.array([p["metrics"].get(m, {}).get("q95", math.nan) for p in summary["grid"]])
            ax.fill_between(x, lo, hi, alpha=0.3, label="5-95 %")
            ax.plot(x, med, "o-", label="median")
            ax.set_xlabel(grid_inputs[0])
            if np.all(x > 0) and x.max() / x.min() > 20:
                ax.set_xscale("log")
            if np.nanmin(lo) > 0 and np.nanmax(hi) / np.nanmin(lo) > 100:
                ax.set_yscale("log")
            ax.legend(fontsize=7)
        else:
            v = np.array([r["metrics"].get(m, math.nan) for r in rows if r["status"] == "ok"])
            v = v[np.isfinite(v)]
            if v.size:
                if v.min() > 0 and v.max() / v.min() > 100:
                    ax.hist(v, bins=np.geomspace(v.min(), v.max(), 30))
                    ax.set_xscale("log")
                else:
                    ax.hist(v, bins=30)
            ax.set_ylabel("samples [count]")
        ax.set_title(m, fontsize=8)
    for ax in axes[len(metric_cols):]:
        ax.set_visible(False)
    c = summary["status"]
    fig.suptitle(f"{title}: {summary['samples']} samples ({c['ok']} ok, {c['diverged']} "
                 f"diverged, {c['error']} failed)", fontsize=9)
    fig.tight_layout()
    path = out / "sweep.png"
    with replacing(path) as tmp:
        fig.savefig(tmp, dpi=100, format="png")
    return path
