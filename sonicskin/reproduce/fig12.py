"""Fig. 12: warm-up after power-on and Alg. 2's online updating; two months at a daily temperature swing."""

from __future__ import annotations

import numpy as np

from ..features import FeatureSpec, touch_mask
from ..kinds import NETWORK
from ..plots import MODEL_STYLE
from .context import MODEL, NEVER_S, Context, deployed_data, first_session_split, plt

ALPHAS = {"5 min": 300.0, "20 min": 1200.0, "60 min": 3600.0, "never": None}


def _per_session(ctx: Context, k: str, d, train: np.ndarray, sessions: list[str]) -> list[float]:
    """Accuracy on each later session's touch chirps, the recording replayed as one stream from power-on."""
    t = d[0].table
    p = ctx.predict(k, d, ~train, one_stream=True)
    te = t.select(~train)
    out = []
    for s in sessions:
        m = (te["session"] == s) & touch_mask(te)
        out.append(float(np.mean(p.location[m] == te["location"][m])))
    return out


def _drift_run(ctx: Context, name: str, axis: str, unit_s: float, rows):
    """A drift dataset trained on its first session: the dataset, its later sessions, the training mask, OSPA's bins and
    a dict of each later session's mean time (``axis``, in units of ``unit_s`` seconds) and temperature over its
    ``rows(table)``."""
    ds, t, train, _, bins = first_session_split(ctx, name)
    later = sorted(set(t["session"]))[1:]
    res: dict = {axis: [], "temperature_c": []}
    for s in later:
        m = (t["session"] == s) & rows(t)
        res[axis].append(float(t["time_s"][m].mean() / unit_s))
        res["temperature_c"].append(float(t["temperature_c"][m].mean()))
    return ds, later, train, bins, res


def run(ctx: Context) -> dict:
    ds, later, train, bins, res = _drift_run(ctx, "drift-2h", "minutes", 60, touch_mask)
    for name, alpha in ALPHAS.items():
        a = NEVER_S if alpha is None else alpha
        # the network (20 min and never) as deployed, on every usable bin; the SVM's bins are their first 300
        d = (deployed_data(ctx, ds, train, alpha_s=a) if ctx.net and name in ("20 min", "never") else
             ctx.data(ds, train=train, bins=bins, alpha_s=a))
        for k in ctx.kinds:
            if name not in ("20 min", "never") and k == NETWORK:
                continue
            res[f"{k} alpha={name}"] = _per_session(ctx, k, d, train, later)
    out = ctx.save(draw(res), "fig12.png", res)
    out["two_months"] = two_months(ctx)
    return out


def draw(res: dict):
    """Accuracy over time, one line per distinct curve: settings (model, updating interval) whose curves are identical
    share one line and one legend entry, so no entry names a hidden line."""
    groups: dict = {}
    for key, v in res.items():
        if " alpha=" in key:
            k, alpha = key.split(" alpha=")
            groups.setdefault(tuple(np.round(np.asarray(v, float), 9)), []).append((k, alpha))
    fig, ax = plt().subplots(figsize=(8, 5))
    # Shared curves first (underneath), so a single setting that differs only slightly stays visible on top.
    for i, (v, members) in enumerate(sorted(groups.items(), key=lambda g: -len(g[1]))):
        kinds = {k for k, _ in members}
        st = MODEL_STYLE[MODEL[kinds.pop()]] if len(kinds) == 1 else {"ls": "-", "lw": 2.0, "alpha": 1.0, "marker": "s"}
        ax.plot(res["minutes"], v, color=f"C{i}", ls=st["ls"], lw=st["lw"], alpha=st["alpha"], marker=st["marker"], ms=5,
                label=_label(members))
    ax.set(xlabel="minutes since power-on", ylabel="accuracy (touch chirps)", title="Fig. 12: warm-up and online updating")
    # Below the axes (covers no line), short entries: settings with identical curves share one line and one entry.
    ax.legend(fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.16), ncol=2,
              title="reference update (model); one line per distinct curve", title_fontsize=8)
    ax.grid(alpha=0.3)
    return fig


def _label(members) -> str:
    """One short legend entry for settings sharing a curve: 'every 5 min (SVM); every 20 min (both models)'."""
    by: dict[str, list[str]] = {}
    for k, a in members:
        by.setdefault("no updating" if a == "never" else "every " + a, []).append(MODEL[k])
    return "; ".join(f"{a} ({'both models' if len(set(ms)) == len(MODEL) else ', '.join(sorted(set(ms)))})"
                     for a, ms in by.items())


def two_months(ctx: Context) -> dict:
    ds, later, train, bins, out = _drift_run(ctx, "drift-2months", "days", 86400, lambda t: np.ones(len(t["session"]), bool))
    for name, alpha in (("with updating", FeatureSpec.alpha_s), ("without", NEVER_S)):
        d = deployed_data(ctx, ds, train, alpha_s=alpha) if ctx.net else ctx.data(ds, train=train, bins=bins, alpha_s=alpha)
        for k in ctx.kinds:
            out[f"{k} {name}"] = _per_session(ctx, k, d, train, later)
    return out
