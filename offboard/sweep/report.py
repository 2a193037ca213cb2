"""A sweep's report, from its Parquet rows: success rate, percentiles, sensitivity, plots.

- success rate: flights ``complete`` (flown to the end, on track, never back on the ground
  with the reference in the air) over all flights, and the count of each status;
- percentiles (5, 50, 95, 99) of every metric over the complete flights (a diverged flight's
  RMS measures nothing but how long it lasted);
- sensitivity: for every swept number, Spearman's rank correlation with failure (status not
  complete, over all flights) and with the whole flight's 3D RMS (over the complete ones),
  ranked by the larger of the two in magnitude: which parameters drive failure and error;
- plots (headless, Agg): histogram and CDF of the RMS, the RMS against each swept parameter,
  and a failure map over the two top-ranked parameters.
"""

from __future__ import annotations

import math
from typing import Any
from pathlib import Path

import numpy as np

from offboard.sweep.spec import PARAMETERS, ParameterKind, SweepSpec

PERCENTILES = (5, 50, 95, 99)
RMS = "rms_whole_m"


def read_rows(path: Path) -> dict[str, np.ndarray]:
    """The Parquet file's columns, sorted by flight index."""
    import pyarrow.parquet as pq

    table = pq.read_table(path)
    cols = {name: table.column(name).to_numpy(zero_copy_only=False) for name in table.column_names}
    order = np.argsort(cols["flight"], kind="stable")
    return {k: np.asarray(v)[order] for k, v in cols.items()}


def _ranks(values: np.ndarray) -> np.ndarray:
    """Average ranks (ties share their mean rank), as Spearman's correlation wants."""
    order = np.argsort(values, kind="stable")
    ranks = np.empty(len(values))
    sorted_values = values[order]
    start = 0
    for end in range(1, len(values) + 1):
        if end == len(values) or sorted_values[end] != sorted_values[start]:
            ranks[order[start:end]] = 0.5 * (start + end - 1)
            start = end
    return ranks


def spearman(a: np.ndarray, b: np.ndarray) -> float:
    """Spearman's rank correlation of two samples; NaN when either is constant or too short."""
    ok = np.isfinite(a) & np.isfinite(b)
    a, b = a[ok], b[ok]
    if len(a) < 3:
        return math.nan
    ra, rb = _ranks(a), _ranks(b)
    sa, sb = np.std(ra), np.std(rb)
    if sa == 0 or sb == 0:
        return math.nan
    return float(np.mean((ra - ra.mean()) * (rb - rb.mean())) / (sa * sb))


def summary(spec: SweepSpec, rows: dict[str, np.ndarray]) -> dict:
    """The report's figures (module docstring) as a dict (strict-JSON-able via ``jsonout``)."""
    status = rows["status"].astype(str)
    n = len(status)
    ok = status == "complete"
    counts = {s: int(np.sum(status == s)) for s in sorted(set(status.tolist()))}
    metrics = [c for c in rows if c.startswith(("rms_", "max_")) or c in ("final_error_m", "peak_tilt_deg",
                                                                         "peak_thrust_n", "converge_s")]  # fmt: skip
    percentiles = {}
    for c in metrics:
        v = rows[c][ok].astype(float)
        v = v[np.isfinite(v)]
        percentiles[c] = {f"p{q}": (float(np.percentile(v, q)) if len(v) else math.nan) for q in PERCENTILES}
        percentiles[c]["samples"] = int(len(v))
    failed = (~ok).astype(float)
    sensitivity: list[dict[str, Any]] = []
    for name in spec.swept:
        if PARAMETERS[name].kind is not ParameterKind.NUMBER:
            continue
        x = rows[name].astype(float)
        rho_fail = spearman(x, failed) if 0 < failed.sum() < n else math.nan
        rho_rms = spearman(x[ok], rows[RMS][ok].astype(float)) if ok.sum() >= 3 else math.nan
        score = max((abs(r) for r in (rho_fail, rho_rms) if math.isfinite(r)), default=math.nan)
        sensitivity.append({"parameter": name, "rho_failure": rho_fail, "rho_rms": rho_rms, "score": score})
    sensitivity.sort(key=lambda s: -s["score"] if math.isfinite(s["score"]) else math.inf)
    return {
        "sweep": spec.name,
        "source": spec.source,
        "flights": n,
        "success_rate": float(ok.mean()) if n else math.nan,
        "statuses": counts,
        "percentiles": percentiles,
        "sensitivity": sensitivity,
    }


def format_report(s: dict) -> str:
    """The report as Markdown (also what the command prints)."""
    lines = [f"# sweep {s['sweep']}: {s['flights']} flights", ""]
    rate = s["success_rate"]
    lines.append(f"success rate {100 * rate:.1f} % ("
                 + ", ".join(f"{k} {v}" for k, v in s["statuses"].items()) + ")")  # fmt: skip
    lines += ["", "| metric (complete flights) | " + " | ".join(f"p{q}" for q in PERCENTILES) + " |",
              "|---|" + "---:|" * len(PERCENTILES)]  # fmt: skip
    for name, p in s["percentiles"].items():
        if p["samples"]:
            lines.append(f"| {name} | " + " | ".join(f"{p[f'p{q}']:.4g}" for q in PERCENTILES) + " |")
    if s["sensitivity"]:
        lines += ["", "| sensitivity: parameter | rho with failure | rho with RMS |", "|---|---:|---:|"]
        for r in s["sensitivity"]:
            def f(v: float) -> str:
                return f"{v:+.3f}" if math.isfinite(v) else "-"

            lines.append(f"| {r['parameter']} | {f(r['rho_failure'])} | {f(r['rho_rms'])} |")
    return "\n".join(lines)


def write_plots(spec: SweepSpec, rows: dict[str, np.ndarray], s: dict, run_dir: Path) -> list[Path]:
    """The report's figures as PNG files in ``run_dir`` (module docstring)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    status = rows["status"].astype(str)
    ok = status == "complete"
    rms = rows[RMS].astype(float)
    out: list[Path] = []
    good = rms[ok & np.isfinite(rms)]
    fig, (ax1, ax2) = plt.subplots(1, 2, figsize=(10, 4))
    if len(good):
        ax1.hist(good, bins=min(50, max(5, len(good) // 10)))
        ax2.plot(np.sort(good), np.arange(1, len(good) + 1) / len(rms))
    ax1.set(xlabel="3D RMS error, whole flight (m)", ylabel="flights", title="complete flights")
    ax2.set(xlabel="3D RMS error (m)", ylabel="fraction of all flights", title="CDF", ylim=(0, 1))
    fig.suptitle(f"{spec.name}: {len(rms)} flights, {100 * s['success_rate']:.1f} % complete")
    fig.tight_layout()
    out.append(run_dir / "rms-histogram.png")
    fig.savefig(out[-1], dpi=100)
    plt.close(fig)
    swept = [r["parameter"] for r in s["sensitivity"]]
    if swept:
        cols = min(3, len(swept))
        nrows = math.ceil(len(swept) / cols)
        fig, axes = plt.subplots(nrows, cols, figsize=(4 * cols, 3.2 * nrows), squeeze=False)
        for ax, name in zip(axes.flat, swept):
            x = rows[name].astype(float)
            ax.scatter(x[ok], rms[ok], s=4, label="complete")
            if (~ok).any():
                top = np.nanmax(rms[ok]) if ok.any() else 1.0
                ax.scatter(x[~ok], np.full(int((~ok).sum()), top), s=8, marker="x", color="red", label="failed (at top)")
            ax.set(xlabel=name, ylabel="3D RMS (m)")
        for ax in list(axes.flat)[len(swept):]:
            ax.axis("off")
        axes.flat[0].legend(fontsize=7)
        fig.tight_layout()
        out.append(run_dir / "rms-vs-parameters.png")
        fig.savefig(out[-1], dpi=100)
        plt.close(fig)
    if len(swept) >= 2:
        a, b = swept[0], swept[1]
        fig, ax = plt.subplots(figsize=(5.5, 4.5))
        colours = {"complete": "tab:green", "diverged": "tab:red", "crashed": "tab:orange"}
        for st, colour in colours.items():
            m = status == st
            if m.any():
                ax.scatter(rows[a][m].astype(float), rows[b][m].astype(float), s=6, color=colour, label=f"{st} ({int(m.sum())})")
        ax.set(xlabel=a, ylabel=b, title="failure map")
        ax.legend(fontsize=7)
        fig.tight_layout()
        out.append(run_dir / "failure-map.png")
        fig.savefig(out[-1], dpi=100)
        plt.close(fig)
    return out
