"""Fig. 6b: OSPA on the moving robot: every band bin (no matched filter, no selection) vs OSPA's 300."""

from __future__ import annotations

import numpy as np

from .context import MODEL, Context, first_session_split, plt


def run(ctx: Context) -> dict:
    ds, t, train, test, bins = first_session_split(ctx, "moving")
    every = ctx.data(ds, train=train, bins=np.arange(ds.rig.n_band), notches=False)
    ospa = ctx.data(ds, train=train, bins=bins)
    res = {k: {"all_bins": ctx.evaluate(k, every, test)["accuracy"], "ospa": ctx.evaluate(k, ospa, test)["accuracy"]}
           for k in ctx.kinds}
    fig, ax = plt().subplots(figsize=(6, 3.5))
    x = np.arange(2)
    for i, k in enumerate(res):
        ax.bar(x + 0.38 * i, [res[k]["all_bins"], res[k]["ospa"]], 0.36, label=MODEL[k])
    ax.set_xticks(x + 0.19, [f"all {ds.rig.n_band} bins", "OSPA 300 bins"])
    ax.set(ylim=(0, 1), ylabel="accuracy", title="Fig. 6b: moving robot")
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1))  # outside: bars reach 1
    return ctx.save(fig, "fig6b.png", res)
