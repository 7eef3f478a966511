"""Fig. 13: force curve models (R2 per location) on E (every band bin) and E^O (OSPA's bins)."""

from __future__ import annotations

import numpy as np

from ..features import quiet_mask, touch_mask
from ..force import MODELS, energy_db, fit_curve
from ..kinds import NETWORK
from .context import Context, deployed_data, first_session_split, plt


def run(ctx: Context) -> dict:
    ds, t, train, test, bins = first_session_split(ctx, "stationary")
    tr = t.select(train)
    touch = touch_mask(tr)
    ref = tr.X[quiet_mask(tr)].mean(axis=0)
    res: dict = {}
    for feat, b in (("E (all band bins)", np.arange(ds.rig.n_band)), ("E^O (OSPA bins)", bins)):
        E = energy_db(tr.X, b, ref)
        res[feat] = {}
        for model in MODELS:
            r2 = [fit_curve(E[touch & (tr["location"] == k)], tr["force_n"][touch & (tr["location"] == k)], model).r2
                  for k in ds.layout.ids if (touch & (tr["location"] == k)).sum() > 6]
            res[feat][model] = float(np.mean(r2))
    if ctx.net:  # the deployed network's force on its own training session (replayed as a stream)
        p = ctx.predict(NETWORK, deployed_data(ctx, ds, train), train)
        m = touch & p.touch
        g = tr["force_n"][m]
        res["network (training fit)"] = float(1 - np.sum((p.force_n[m] - g) ** 2) / np.sum((g - g.mean()) ** 2))
    fig, ax = plt().subplots(figsize=(8.5, 3.5))
    names = list(MODELS)
    for i, feat in enumerate(k for k in res if isinstance(res[k], dict)):
        ax.bar(np.arange(len(names)) + 0.4 * i, [res[feat][n] for n in names], 0.38, label=feat)
    if "network (training fit)" in res:
        ax.axhline(res["network (training fit)"], color="k", ls="--", lw=1, label="network force head")
    ax.set_xticks(np.arange(len(names)) + 0.2, names)
    ax.set(ylabel="mean R2 per location", ylim=(0, 1.05), title="Fig. 13: force curve models")
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1))  # outside: bars reach 1
    return ctx.save(fig, "fig13.png", res)
