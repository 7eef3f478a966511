"""The paper's Sec. V experiments, one function each (:data:`sonicskin.reproduce.EXPERIMENTS`): a
:class:`~.context.Context` of one simulator seed in, its numbers out, its figure written."""

from __future__ import annotations

import numpy as np

from ..features import FeatureSpec, quiet_mask, touch_mask
from ..force import MODELS, energy_db, fit_curve
from ..kinds import BASELINE, NETWORK
from ..plots import MODEL_STYLE, cdf_panel, confusion_panel
from .context import MATERIALS, MODEL, NEVER_S, Context, deployed_data, first_session_split, plt


# -- Fig. 6b: OSPA on the moving robot: every band bin (no matched filter, no selection) vs OSPA's 300.
def fig6b(ctx: Context) -> dict:
    ds, t, train, test, bins = first_session_split(ctx, "moving")
    every = ctx.data(ds, train=train, bins=np.arange(ds.rig.n_band), notches=False)
    ospa = ctx.data(ds, train=train, bins=bins)
    res = {k: {"all_bins": ctx.evaluate(k, every, test)["accuracy"], "ospa": ctx.evaluate(k, ospa, test)["accuracy"]} for k in ctx.kinds}
    fig, ax = plt().subplots(figsize=(6, 3.5))
    x = np.arange(2)
    for i, k in enumerate(res):
        ax.bar(x + 0.38 * i, [res[k]["all_bins"], res[k]["ospa"]], 0.36, label=MODEL[k])
    ax.set_xticks(x + 0.19, [f"all {ds.rig.n_band} bins", "OSPA 300 bins"])
    ax.set(ylim=(0, 1), ylabel="accuracy", title="Fig. 6b: moving robot")
    ax.legend(loc="upper left", bbox_to_anchor=(1.01, 1))  # outside: bars reach 1
    return ctx.save(fig, "fig6b.png", res)


# -- Fig. 11: accuracy against OSPA's gamma on the moving robot.
def fig11_sizes(quick: bool) -> dict:
    """The sweep: gammas, the SVM's training resamples and the network's training seeds (per simulator seed)."""
    if quick:
        return {"gammas": [100, 300, 1000], "svm_seeds": [0, 1], "net_seeds": [0, 1]}
    return {"gammas": list(range(100, 1001, 100)), "svm_seeds": [0, 1, 2], "net_seeds": [0, 1, 2]}


def fig11(ctx: Context) -> dict:
    ds = ctx.dataset("moving")
    t = ctx.table(ds)
    first = sorted(set(t["session"]))[0]
    train = t["session"] == first
    test = ~train
    sz = fig11_sizes(ctx.quick)
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


# -- Fig. 12: warm-up after power-on and Alg. 2's online updating; two months at a daily temperature swing.
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
    """A drift dataset trained on its first session, with each later session's mean time and temperature."""
    ds, t, train, _, bins = first_session_split(ctx, name)
    later = sorted(set(t["session"]))[1:]
    res: dict = {axis: [], "temperature_c": []}
    for s in later:
        m = (t["session"] == s) & rows(t)
        res[axis].append(float(t["time_s"][m].mean() / unit_s))
        res["temperature_c"].append(float(t["temperature_c"][m].mean()))
    return ds, later, train, bins, res


def fig12(ctx: Context) -> dict:
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
    out = ctx.save(draw_fig12(res), "fig12.png", res)
    out["two_months"] = two_months(ctx)
    return out


def draw_fig12(res: dict):
    """Accuracy over time, one line per distinct curve (identical curves share one line and legend entry)."""
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
    return "; ".join(f"{a} ({'both models' if len(set(ms)) == len(MODEL) else ', '.join(sorted(set(ms)))})" for a, ms in by.items())


def two_months(ctx: Context) -> dict:
    ds, later, train, bins, out = _drift_run(ctx, "drift-2months", "days", 86400, lambda t: np.ones(len(t["session"]), bool))
    for name, alpha in (("with updating", FeatureSpec.alpha_s), ("without", NEVER_S)):
        d = deployed_data(ctx, ds, train, alpha_s=alpha) if ctx.net else ctx.data(ds, train=train, bins=bins, alpha_s=alpha)
        for k in ctx.kinds:
            out[f"{k} {name}"] = _per_session(ctx, k, d, train, later)
    return out


# -- Fig. 13: force curve models (R2 per location) on E (every band bin) and E^O (OSPA's bins).
def fig13(ctx: Context) -> dict:
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


# -- Table I (force), the stationary robot, Fig. 14 (moving robot) and Fig. 15 (unseen people).
def table1(ctx: Context) -> dict:
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


# -- Fig. 16: other materials (two points 1.2 cm apart) and the aluminium plate with 36 markers.
def fig16(ctx: Context) -> dict:
    res: dict = {}
    for name in [f"two-points-{m}" for m in MATERIALS] + ["plate-aluminium"]:
        ds, t, train, test, bins = first_session_split(ctx, name)
        d = deployed_data(ctx, ds, train)
        key = "aluminium plate, 36 markers" if name == "plate-aluminium" else name.removeprefix("two-points-")
        res[key] = {k: ctx.evaluate(k, d, test) for k in ctx.kinds}
    return ctx.save(draw_fig16(res, ctx.kinds), "fig16.png", res)


def draw_fig16(res: dict, kinds: list[str]):
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
