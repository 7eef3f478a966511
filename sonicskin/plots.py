"""Figure pieces shared by the reports (``compare``, ``evaluate``).  Two models drawn in one panel differ in colour,
line style and width, and a note says when their curves coincide (so one never hides the other)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

__all__ = ["pyplot", "location_names", "confusion_panel", "cdf_panel", "force_panel", "detection_panel", "MODEL_STYLE"]

# How each model is drawn wherever both appear: colour, line style, width, marker.
MODEL_STYLE = {
    "network": {"color": "C0", "ls": "-", "lw": 3.0, "alpha": 0.75, "marker": "o"},
    "SVM": {"color": "C3", "ls": "--", "lw": 1.5, "alpha": 1.0, "marker": "x"},
}


def pyplot():
    """matplotlib's pyplot on the file backend (every report draws into files), imported when a report draws."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def location_names(data: str | Path | None, layout) -> list[str]:
    """The user's names of ``layout``'s locations (an imported dataset's labels), else the ids."""
    labels: dict = {}
    if data is not None:
        try:
            labels = json.loads((Path(data) / "dataset.json").read_text()).get("source", {}).get("labels") or {}
        except (OSError, ValueError, AttributeError):
            labels = {}
    return [str(labels.get(str(i), i)) for i in layout.ids]


def confusion_panel(fig, ax, confusion, names: list[str], title: str):
    """Row-normalised confusion matrix with the location names on both axes and a labelled colourbar."""
    cm = np.asarray(confusion, float)
    rows = cm.sum(axis=1, keepdims=True)
    cm = np.where(rows > 0, cm / np.maximum(rows, 1), np.nan)  # a location never touched in the test: no row, not 0 %
    cmap = pyplot().colormaps["viridis"].with_extremes(bad="0.85")
    im = ax.imshow(cm, cmap=cmap, vmin=0, vmax=1)
    if (rows == 0).any():
        title += f"\n(grey rows: {int((rows == 0).sum())} locations not touched in the test)"
    n = len(names)
    step = max(1, int(np.ceil(n / 16)))  # at most ~16 tick labels per axis
    ticks = np.arange(0, n, step)
    ax.set_xticks(ticks, [names[i] for i in ticks], fontsize=7, rotation=90 if max(map(len, names)) > 3 else 0)
    ax.set_yticks(ticks, [names[i] for i in ticks], fontsize=7)
    ax.set(xlabel="predicted location", ylabel="true location", title=title)
    cb = fig.colorbar(im, ax=ax, fraction=0.046, pad=0.04)
    cb.set_label("share of the true location's touch chirps")
    return im


def cdf_panel(ax, errors: dict[str, np.ndarray], title: str = "localization error CDF") -> None:
    """Error CDF of each model over its whole range, the 2 and 3 cm thresholds in the legend."""
    emax = 0.0
    first = None
    lowest = 1.0  # the smallest share any curve shows past x = 0: the y-axis starts just below it
    # The thicker line first, so a thinner one on the same path stays visible on top of it.
    for name, err in sorted(errors.items(), key=lambda kv: -MODEL_STYLE.get(kv[0], {}).get("lw", 1.5)):
        e = np.sort(np.asarray(err, float))
        c = np.arange(1, e.size + 1) / max(e.size, 1)
        st = MODEL_STYLE.get(name, {})
        same = first is not None and np.array_equal(e, first[1])
        label = name + (f" (identical to {first[0]})" if same else "")
        ax.step(np.r_[0.0, e], np.r_[0.0, c], where="post", label=label, color=st.get("color"), ls=st.get("ls", "-"),
                lw=st.get("lw", 1.5), alpha=st.get("alpha", 1.0))
        emax = max(emax, float(e.max()) if e.size else 0.0)
        lowest = min(lowest, np.searchsorted(e, e[0], side="right") / e.size if e.size else 1.0)  # share at the first step
        first = first or (name, e)
    ax.axvline(2, color="gray", lw=0.8, ls=":", label="2 cm")
    ax.axvline(3, color="gray", lw=0.8, ls="-.", label="3 cm")
    # A y-axis from 0 to 1 draws a flat line at the top when every model is right on 95 % of chirps: the axis starts
    # just below the lowest curve (in steps of 5 %; at 0 when a curve starts below 50 %), and the label says so when it does not start at 0.
    y0 = np.floor((lowest - 0.03) * 20) / 20 if lowest >= 0.5 else 0.0
    ylabel = "share of touch chirps with error ≤ x" + (f" (axis from {y0:.0%})" if y0 > 0 else "")
    ax.set(xlabel="localization error (cm)", ylabel=ylabel, ylim=(y0, 1.0 + 0.02 * (1 - y0)),
           xlim=(-0.05 * max(emax, 4.0), 1.05 * max(emax, 4.0)), title=title)
    # Below the axes, clear of the tick labels and the axis label whatever the panel's height: covers no data.
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, 0), borderaxespad=4.3, ncol=2, fontsize=8)
    ax.grid(alpha=0.3)


def force_panel(ax, points: dict[str, tuple[np.ndarray, np.ndarray] | None], reason: str = "") -> None:
    """Predicted vs true force of each model, with the ideal line; without a force sensor the panel says so."""
    ax.set(xlabel="true force (N)", ylabel="predicted force (N)", title="force: predicted vs true")
    drawn = False
    hi = 0.0
    for name, pt in points.items():
        if pt is None:
            continue
        g, p = (np.asarray(v, float) for v in pt)
        ok = np.isfinite(g) & np.isfinite(p)
        if not ok.any():
            continue
        st = MODEL_STYLE.get(name, {})
        ax.scatter(g[ok], p[ok], s=10 if name == "network" else 14, marker=st.get("marker", "o"), color=st.get("color"),
                   alpha=0.45 if name == "network" else 0.8, linewidths=1, label=f"{name} ({ok.sum()} chirps)")
        hi = max(hi, float(np.max(g[ok])), float(np.max(p[ok])))
        drawn = True
    if not drawn:
        why = reason.removeprefix("absent: ") if reason else "no force sensor (the data has no measured force)"
        ax.text(0.5, 0.5, "n/a: " + why.replace(" (", "\n("), ha="center", va="center", transform=ax.transAxes, fontsize=10, wrap=True)
        ax.set_xticks([]); ax.set_yticks([])
        return
    hi = 1.05 * hi or 1.0
    ax.plot([0, hi], [0, hi], color="gray", lw=0.8, label="predicted = true")
    # The mean prediction per band of true force: a model that saturates (reads 13 N presses as 8 N) shows a bending
    # line here and a sentence in the panel, which one RMSE figure hides.
    notes = []
    for name, pt in points.items():
        if pt is None:
            continue
        g, p = (np.asarray(v, float) for v in pt)
        ok = np.isfinite(g) & np.isfinite(p)
        if ok.sum() < 20 or np.ptp(g[ok]) <= 0:
            continue
        g, p = g[ok], p[ok]
        edges = np.unique(np.quantile(g, np.linspace(0, 1, 9)))
        band = np.clip(np.searchsorted(edges, g, side="right") - 1, 0, len(edges) - 2)
        gx = np.array([g[band == b].mean() for b in range(len(edges) - 1) if (band == b).any()])
        py = np.array([p[band == b].mean() for b in range(len(edges) - 1) if (band == b).any()])
        st = MODEL_STYLE.get(name, {})
        ax.plot(gx, py, color=st.get("color"), ls=st.get("ls", "-"), lw=st.get("lw", 1.5), alpha=st.get("alpha", 1.0),
                zorder=3 + (st.get("lw", 1.5) < 2), label=f"{name}: mean per force band")  # the thinner on top
        top = g >= np.quantile(g, 0.9)
        ratio = p[top].mean() / g[top].mean()
        if ratio < 0.85:
            notes.append(f"{name} under-reads the strongest tenth of presses: {g[top].mean():.1f} N read as "
                         f"{p[top].mean():.1f} N")
    if notes:
        ax.text(0.02, 0.98, "\n".join(notes), transform=ax.transAxes, va="top", fontsize=8,
                bbox={"facecolor": "white", "alpha": 0.85, "edgecolor": "0.7"})
    ax.set(xlim=(0, hi), ylim=(0, hi))
    # Below the axes, clear of the tick labels and the axis label whatever the panel's height: covers no data.
    ax.legend(loc="upper center", bbox_to_anchor=(0.5, 0), borderaxespad=4.3, ncol=2, fontsize=8)
    ax.grid(alpha=0.3)


def detection_panel(ax, detection: dict[str, dict], title: str = "touch detection") -> None:
    """False and missed touches of each model as bars; a model whose detection is not measurable says why."""
    kinds = [("false_touch_rate", "false touches\n(share of hands-off chirps)"),
             ("missed_touch_rate", "missed touches\n(share of touch chirps)")]
    ok = {n: d for n, d in detection.items() if d and "false_touch_rate" in d}
    ax.set_title(title)
    if not ok:
        why = next((d.get("reason", "") for d in detection.values() if d), "") or "no hands-off chirps"
        ax.text(0.5, 0.5, "n/a: " + why.removeprefix("not measurable on this data: ").replace(" (", "\n("),
                ha="center", va="center", transform=ax.transAxes, fontsize=10, wrap=True)
        ax.set_xticks([]); ax.set_yticks([])
        return
    x = np.arange(len(kinds))
    w = 0.5 / len(ok)
    top = 0.0
    for i, (name, d) in enumerate(ok.items()):
        v = np.array([100 * float(d[k]) for k, _ in kinds])
        st = MODEL_STYLE.get(name, {})
        bars = ax.bar(x + (i - (len(ok) - 1) / 2) * w, v, w, color=st.get("color"), label=name,
                      hatch=None if i == 0 else "//", edgecolor="black", linewidth=0.5)
        ax.bar_label(bars, [f"{u:.1f} %" for u in v], fontsize=8, padding=2)
        top = max(top, float(v.max()))
    ax.set_xticks(x, [lab for _, lab in kinds], fontsize=8)
    ax.set(ylabel="rate (%)", ylim=(0, max(1.0, 1.6 * top)), xlim=(-0.6, len(kinds) - 0.4))
    ax.legend(fontsize=8, loc="best")  # headroom above the bars: "best" finds a place that covers none
    ax.grid(alpha=0.3, axis="y")
