"""Fig. 16: other materials (two points 1.2 cm apart) and the aluminium plate with 36 markers."""

from __future__ import annotations

import numpy as np

from ..plots import MODEL_STYLE
from .context import MATERIALS, MODEL, Context, deployed_data, first_session_split, plt


def run(ctx: Context) -> dict:
    res: dict = {}
    for name in [f"two-points-{m}" for m in MATERIALS] + ["plate-aluminium"]:
        ds, t, train, test, bins = first_session_split(ctx, name)
        d = deployed_data(ctx, ds, train)
        key = "aluminium plate, 36 markers" if name == "plate-aluminium" else name.removeprefix("two-points-")
        res[key] = {k: ctx.evaluate(k, d, test) for k in ctx.kinds}
    return ctx.save(draw(res, ctx.kinds), "fig16.png", res)


def draw(res: dict, kinds: list[str]):
    """Accuracy and force RMSE per material, both models side by side; the legend sits above the bars."""
    fig, ax = plt().subplots(1, 2, figsize=(11, 4.2))
    names = list(res)
    x = np.arange(len(names))
    for i, k in enumerate(kinds):
        col = MODEL_STYLE[MODEL[k]]["color"]
        ax[0].bar(x + 0.4 * i, [res[n][k]["accuracy"] for n in names], 0.38, label=MODEL[k], color=col)
        ax[1].bar(x + 0.4 * i, [res[n][k]["force"]["rmse_n"] for n in names], 0.38, label=MODEL[k], color=col)
    for a, yl in zip(ax, ("accuracy (touch chirps)", "force RMSE (N)")):
        a.set_xticks(x + 0.2 * (len(kinds) - 1), [n.replace(", 36 markers", "\n36 markers") for n in names], fontsize=7)
        a.set(ylabel=yl)
        a.grid(alpha=0.3, axis="y")
    ax[0].set_ylim(0, 1)
    fig.legend(*ax[0].get_legend_handles_labels(), loc="upper right", ncol=len(kinds), fontsize=8)
    fig.suptitle("Fig. 16: materials", x=0.02, ha="left")
    return fig
