"""Fig. 11: accuracy against OSPA's gamma on the moving robot."""

from __future__ import annotations

import numpy as np

from ..kinds import BASELINE, NETWORK
from .context import Context, plt


def sizes(quick: bool) -> dict:
    """The sweep: gammas, the SVM's training resamples and the network's training seeds (per simulator seed)."""
    if quick:
        return {"gammas": [100, 300, 1000], "svm_seeds": [0, 1], "net_seeds": [0, 1]}
    return {"gammas": list(range(100, 1001, 100)), "svm_seeds": [0, 1, 2], "net_seeds": [0, 1, 2]}


def run(ctx: Context) -> dict:
    ds = ctx.dataset("moving")
    t = ctx.table(ds)
    first = sorted(set(t["session"]))[0]
    train = t["session"] == first
    test = ~train
    sz = sizes(ctx.quick)
    order = ctx.bins(ds, t, train, max(sz["gammas"]))
    res = {k: {} for k in ctx.kinds}
    for g in sz["gammas"]:
        for k in res:
            # The SVM is deterministic; its spread over seeds comes from resampling the training presses (80 %).
            accs = []
            for s in sz[f"{k}_seeds"]:
                keep = None
                if k == BASELINE and s > 0:
                    keep = np.random.default_rng(s).random(len(t)) < 0.8
                d = ctx.data(ds, train=train, bins=order[:g], keep=keep)
                accs.append(ctx.evaluate(k, d, test, seed=s if k == NETWORK else 0)["accuracy"])
            res[k][g] = accs
    fig, ax = plt().subplots(figsize=(5, 3.5))
    for k, v in res.items():
        g = sorted(v)
        ax.errorbar(g, [np.mean(v[x]) for x in g], yerr=[np.std(v[x]) for x in g], marker="o", capsize=3, label=k)
    ax.set(xlabel="bins selected by OSPA (gamma)", ylabel="accuracy", title="Fig. 11: accuracy vs gamma")
    ax.legend(); ax.grid(alpha=0.3)
    return ctx.save(fig, "fig11.png", res)
