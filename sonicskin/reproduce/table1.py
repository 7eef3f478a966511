"""Table I (force), the stationary robot, Fig. 14 (moving robot) and Fig. 15 (unseen people)."""

from __future__ import annotations

import numpy as np

from ..kinds import NETWORK
from ..plots import cdf_panel, confusion_panel
from .context import MODEL, Context, deployed_data, first_session_split, plt


def run(ctx: Context) -> dict:
    res: dict = {"table1": {}, "stationary": {}, "fig14": {}, "fig15": {}}
    layers: dict[str, str] = {}  # the network's location layer behind each figure
    for name in ("stationary", "moving"):
        ds, t, train, test, bins = first_session_split(ctx, name)
        d = deployed_data(ctx, ds, train)
        for k in ctx.kinds:
            ev = ctx.evaluate(k, d, test)
            res["table1"][f"{name} {k}"] = ev["force"]
            res["fig14" if name == "moving" else "stationary"][k] = ev
        if name == "moving":
            layers["fig14"] = _net_layer(ctx, d)
    n_people = 6 if ctx.quick else 12
    ds = ctx.dataset("multi-person")
    t = ctx.table(ds)
    test_subjects = list(range(n_people - (2 if ctx.quick else 4), n_people))
    test = np.isin(t["session"], sorted(set(t["session"][np.isin(t["subject"], test_subjects) & (t["location"] >= 0)])))
    train = ~test
    d = deployed_data(ctx, ds, train)
    for k in ctx.kinds:
        res["fig15"][k] = ctx.evaluate(k, d, test)
    layers["fig15"] = _net_layer(ctx, d)
    for fig_name in ("fig14", "fig15") if ctx.plots else ():
        kinds = list(res[fig_name])
        same = len(kinds) > 1 and all(np.array_equal(res[fig_name][kinds[0]]["confusion"], res[fig_name][k]["confusion"])
                                      for k in kinds[1:])
        fig, ax = plt().subplots(1, len(kinds) + 1, figsize=(5 * (len(kinds) + 1), 4.3))
        for a, k in zip(ax[:-1], kinds):
            cm = res[fig_name][k]["confusion"]
            confusion_panel(fig, a, cm, [str(i) for i in range(len(cm))], f"{MODEL[k]}: accuracy {res[fig_name][k]['accuracy']:.1%}")
        cdf_panel(ax[-1], {MODEL[k]: res[fig_name][k]["errors_cm"] for k in kinds},
                  "moving robot" if fig_name == "fig14" else "unseen people (leave-subjects-out)")
        title = "Fig. 14" if fig_name == "fig14" else "Fig. 15"
        if same:  # say why: the network's validation chose the SVM's kernel as its location layer
            title += (" (identical panels: both models decide every chirp alike; the network's location layer is "
                      f"'{layers.get(fig_name, '?')}')")
        fig.suptitle(title)
        fig.tight_layout()
        fig.savefig(ctx.out / f"{fig_name}.png", dpi=100)
        plt().close(fig)
        ctx.figs.append(ctx.out / f"{fig_name}.png")
    return res


def _net_layer(ctx: Context, d) -> str:
    """The location layer the deployed network uses (its artifact's ``selection.net``), '' without a network."""
    import json

    if NETWORK not in ctx.kinds:
        return ""
    sel = json.loads((ctx.artifact(NETWORK, d) / "skin.json").read_text()).get("selection", {}).get(NETWORK, {})
    return str(sel.get("location_layer", ""))
