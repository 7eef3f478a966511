"""Figures a reader understands at a glance, and output in the user's words (issue 20.3/20.4).

The figures are caught as they are saved (``Figure.savefig`` wrapped) and inspected as matplotlib
objects: panels, axis labels, labelled colourbars, the user's location names, legends that name
only visible lines and cover no bar."""

from __future__ import annotations

import json
import re

import matplotlib
import numpy as np
import pytest
import yaml

matplotlib.use("Agg")
from matplotlib.figure import Figure  # noqa: E402

from sonicskin.metrics import speed_ratio  # noqa: E402
from sonicskin.rig import Layout  # noqa: E402

NAMES = ["A1", "A2", "B1"]


@pytest.fixture
def saved(monkeypatch):
    """Every figure saved during the test, by file name."""
    figs: dict[str, Figure] = {}
    orig = Figure.savefig

    def keep(self, fname, *a, **k):
        figs[str(fname).rsplit("/", 1)[-1]] = self
        return orig(self, fname, *a, **k)

    monkeypatch.setattr(Figure, "savefig", keep)
    return figs


@pytest.fixture
def named_data(tmp_path):
    """A dataset folder whose locations the user named A1, A2, B1 (as import-wav records them)."""
    d = tmp_path / "lab"
    d.mkdir()
    (d / "dataset.json").write_text(json.dumps({"source": {"kind": "import-wav", "labels": {"0": "A1", "1": "A2", "2": "B1"}}}))
    return d


LAYOUT = Layout(ids=(0, 1, 2), xy_cm=np.array([[0.0, 0.0], [1.2, 0.0], [2.4, 0.0]]))


def _model(errors, acc, force=None):
    cm = [[5, 1, 0], [0, 6, 0], [0, 2, 4]]
    r = {"localization": {"accuracy": acc, "within_2cm": 0.9, "confusion": cm}, "errors_cm": list(errors)}
    if force is None:
        r["force"] = {"measurable": False, "reason": "absent: no force sensor (force_n is empty/NaN)"}
        r["force_points"] = {"true_n": [float("nan")] * 4, "predicted_n": [1.0] * 4}
    else:
        r["force"] = {"rmse_n": 0.5}
        r["force_points"] = {"true_n": force[0], "predicted_n": force[1]}
    return r


def _legend_texts(ax_or_fig) -> list[str]:
    leg = ax_or_fig.get_legend() if hasattr(ax_or_fig, "get_legend") else None
    leg = leg or (ax_or_fig.legends[0] if getattr(ax_or_fig, "legends", None) else None)
    assert leg is not None, "no legend"
    return [t.get_text() for t in leg.get_texts()]


def _colourbars(fig) -> list:
    return [a for a in fig.axes if a.get_label() == "<colorbar>"]


def test_compare_png_has_both_models_distinguishable_a_force_panel_and_names(tmp_path, saved, named_data):
    from sonicskin.compare import save_comparison

    err = [0.0] * 10 + [1.2, 2.4, 14.0]  # a long tail at 14 cm: the axis must reach it
    f_true, f_net, f_svm = [1.0, 2.0, 3.0, 4.0], [1.2, 1.8, 3.3, 3.9], [0.5, 2.5, 2.0, 5.0]
    res = {"data": str(named_data), "models": {"net": _model(err, 0.8, (f_true, f_net)), "svm": _model(err, 0.8, (f_true, f_svm))}}
    save_comparison(res, tmp_path / "cmp", LAYOUT, "t")
    fig = saved["compare.png"]
    panels = [a for a in fig.axes if a.get_label() != "<colorbar>"]
    assert len(panels) == 5  # two confusion matrices, error CDF, force, detection
    # Both confusion matrices: a labelled colourbar each, the user's names on both axes.
    cbs = _colourbars(fig)
    assert len(cbs) == 2 and all(cb.get_ylabel() for cb in cbs)
    for a in panels[:2]:
        assert [t.get_text() for t in a.get_xticklabels()] == NAMES
        assert [t.get_text() for t in a.get_yticklabels()] == NAMES
        assert (a.get_xlabel(), a.get_ylabel()) == ("predicted location", "true location")
    # Error CDF: the whole distribution (both curves reach 1 inside the axis), identical curves said so.
    cdf = panels[2]
    assert cdf.get_xlim()[1] > 14.0
    assert cdf.get_xlabel() == "localization error (cm)" and cdf.get_ylabel()
    labels = _legend_texts(cdf)
    assert "network" in labels and "SVM (identical to network)" in labels and "2 cm" in labels and "3 cm" in labels
    lines = [ln for ln in cdf.get_lines() if ln.get_label() in ("network", "SVM (identical to network)")]
    assert len(lines) == 2
    assert lines[0].get_linestyle() != lines[1].get_linestyle() and lines[0].get_linewidth() != lines[1].get_linewidth()
    assert lines[0].get_color() != lines[1].get_color()
    # Force: predicted vs true of both models, with the ideal line.
    fp = panels[3]
    assert (fp.get_xlabel(), fp.get_ylabel()) == ("true force (N)", "predicted force (N)")
    assert len(fp.collections) == 2
    assert any(t.startswith("network") for t in _legend_texts(fp)) and any(t.startswith("SVM") for t in _legend_texts(fp))
    np.testing.assert_allclose(fp.collections[1].get_offsets(), np.column_stack([f_true, f_svm]))


def test_compare_png_without_force_sensor_says_so(tmp_path, saved, named_data):
    from sonicskin.compare import save_comparison

    res = {"data": str(named_data), "models": {"net": _model([0, 1.2], 0.5), "svm": _model([0, 2.4], 0.5)}}
    save_comparison(res, tmp_path / "cmp", LAYOUT)
    fp = [a for a in saved["compare.png"].axes if a.get_label() != "<colorbar>"][3]
    assert not fp.collections
    assert any(t.get_text().startswith("n/a: no force sensor") for t in fp.texts)
    # Different errors: no "identical" note.
    assert not any("identical" in t for t in _legend_texts([a for a in saved["compare.png"].axes][2]))


def test_localization_png_labels_colourbar_and_thresholds(tmp_path, saved, named_data):
    from sonicskin.evaluate import save_report

    cm = [[3, 1, 0], [0, 4, 0], [0, 0, 4]]
    res = {"dataset": str(named_data), "localization": {"accuracy": 0.75, "within_2cm": 0.9, "confusion": cm},
           "errors_cm": [0.0, 0.0, 1.2, 9.5]}
    save_report(res, tmp_path / "rep", LAYOUT)
    fig = saved["localization.png"]
    cbs = _colourbars(fig)
    assert len(cbs) == 1 and cbs[0].get_ylabel()
    conf, cdf, det = [a for a in fig.axes if a.get_label() != "<colorbar>"]
    assert det.get_title() == "touch detection" and any(t.get_text().startswith("n/a") for t in det.texts)
    assert [t.get_text() for t in conf.get_xticklabels()] == NAMES
    assert {"2 cm", "3 cm"} <= set(_legend_texts(cdf))
    assert cdf.get_xlim()[1] > 9.5


def test_cdf_axis_starts_below_the_lowest_curve_not_at_zero():
    import matplotlib.pyplot as plt

    from sonicskin.plots import cdf_panel

    fig, ax = plt.subplots()
    # 96 % and 98 % of chirps exactly right: a 0-1 axis would draw two flat lines at the top
    cdf_panel(ax, {"network": np.r_[np.zeros(96), [1.2, 2.4, 3.6, 9.0]], "SVM": np.r_[np.zeros(98), [1.2, 2.4]]})
    lo, hi = ax.get_ylim()
    assert lo == pytest.approx(0.90) and hi > 1.0 and "axis from 90%" in ax.get_ylabel()
    fig2, ax2 = plt.subplots()
    cdf_panel(ax2, {"SVM": np.r_[np.zeros(40), np.ones(60)]})  # 40 % right: the axis keeps its 0
    assert ax2.get_ylim()[0] == 0 and "axis from" not in ax2.get_ylabel()
    plt.close("all")


def test_detection_panel_shows_each_models_rates_or_why_not():
    import matplotlib.pyplot as plt

    from sonicskin.plots import detection_panel

    fig, ax = plt.subplots()
    detection_panel(ax, {"network": {"false_touch_rate": 0.177, "missed_touch_rate": 0.004},
                         "SVM": {"false_touch_rate": 0.02, "missed_touch_rate": 0.011}})
    assert len(ax.patches) == 4 and _legend_texts(ax) == ["network", "SVM"]
    heights = sorted(round(p.get_height(), 1) for p in ax.patches)
    assert heights == [0.4, 1.1, 2.0, 17.7]
    assert {"17.7 %", "0.4 %", "2.0 %", "1.1 %"} <= {t.get_text() for t in ax.texts}  # each bar labelled
    fig2, ax2 = plt.subplots()
    detection_panel(ax2, {"SVM": {"measurable": False, "reason": "not measurable on this data: no hands-off chirps"}})
    assert not ax2.patches and [t.get_text() for t in ax2.texts] == ["n/a: no hands-off chirps"]
    plt.close("all")


def test_force_panel_names_a_model_that_saturates():
    import matplotlib.pyplot as plt

    from sonicskin.plots import force_panel

    true = np.linspace(0.5, 15.0, 200)
    fig, ax = plt.subplots()
    force_panel(ax, {"network": (true, true * 1.02), "SVM": (true, np.minimum(true, 8.0))})  # the SVM reads <= 8 N
    note = " ".join(t.get_text() for t in ax.texts)
    assert "SVM under-reads the strongest tenth of presses" in note and "read as 8.0 N" in note
    assert "network under-reads" not in note
    means = [ln for ln in ax.get_lines() if ln.get_label() == "SVM: mean per force band"]
    assert len(means) == 1 and means[0].get_ydata().max() == pytest.approx(8.0)
    plt.close("all")


def test_learning_curve_keeps_its_note_inside_and_says_why_three_passes_give_two_points(tmp_path, saved):
    from sklearn.neighbors import NearestCentroid

    from sonicskin.selection import learning_curve_by_pass, save_learning_curve

    rng = np.random.default_rng(0)
    y = np.tile(np.arange(4), 3)
    passes = np.repeat(np.arange(3), 4)
    X = y[:, None] * 3.0 + rng.normal(0, 1, (12, 2))
    lc = learning_curve_by_pass(NearestCentroid(), X, y, passes, np.arange(12))
    assert lc["presses_per_location"] == [1, 2] and lc["passes_recorded"] == 3
    assert save_learning_curve({"learning_curve": lc}, tmp_path / "lc.png")
    fig = saved["lc.png"]
    ax = fig.axes[0]
    assert [int(t) for t in ax.get_xticks()] == [1, 2, 3]
    fig.canvas.draw()
    (note,) = [t for t in ax.texts if "passes recorded" in t.get_text()]
    assert "k stops at 2" in note.get_text()
    box, frame = note.get_window_extent(), ax.get_window_extent()
    assert frame.x0 <= box.x0 and box.x1 <= frame.x1 and frame.y0 <= box.y0 and box.y1 <= frame.y1
    assert sum(t.get_text().endswith("%") for t in ax.texts) == 2  # each point labelled with its accuracy


def test_ids_when_the_user_gave_no_names(tmp_path):
    from sonicskin.plots import location_names

    assert location_names(tmp_path, LAYOUT) == ["0", "1", "2"]


def test_fig12_legend_names_only_visible_lines():
    from sonicskin.reproduce.experiments import draw_fig12 as _draw_fig12

    same = [0.9, 0.8, 0.85]
    res = {"minutes": [30, 60, 90], "temperature_c": [25, 27, 28], "svm alpha=5 min": same, "svm alpha=20 min": same,
           "svm alpha=60 min": same, "svm alpha=never": [0.9, 0.5, 0.4], "net alpha=20 min": [0.95, 0.9, 0.9],
           "net alpha=never": [0.95, 0.6, 0.5]}
    fig = _draw_fig12(res)
    ax = fig.axes[0]
    labels = _legend_texts(ax)
    assert len(labels) == len(ax.get_lines()) == 4  # the three identical SVM curves are one line, one entry
    assert "every 5 min (SVM); every 20 min (SVM); every 60 min (SVM)" in labels
    # Identical across models too (the network's kernel layer is the SVM's): one line, one short entry.
    res2 = {**res, "net alpha=20 min": same}
    labels2 = _legend_texts(_draw_fig12(res2).axes[0])
    assert len(labels2) == 3 and "every 5 min (SVM); every 20 min (both models); every 60 min (SVM)" in labels2
    assert "no updating (network)" in labels2
    # The legend is below the data area (covers no line) and inside the saved figure; it takes no plot width.
    fig.tight_layout()
    fig.canvas.draw()
    leg, box, page = ax.get_legend().get_window_extent(), ax.get_window_extent(), fig.bbox
    assert leg.y1 <= box.y0 and leg.y0 >= page.y0 and leg.x0 >= page.x0 and leg.x1 <= page.x1
    assert box.width > 0.8 * page.width


def test_fig16_legend_covers_no_bar():
    from sonicskin.reproduce.experiments import draw_fig16 as _draw_fig16

    res = {m: {"svm": {"accuracy": 1.0, "force": {"rmse_n": 0.4}}, "net": {"accuracy": 0.98, "force": {"rmse_n": 0.6}}}
           for m in ("cfrp", "aluminium", "abs", "glass", "wood", "aluminium plate, 36 markers")}
    fig = _draw_fig16(res, ["svm", "net"])
    fig.tight_layout()
    fig.canvas.draw()
    leg = fig.legends[0].get_window_extent()
    bars = [p.get_window_extent() for a in fig.axes for p in a.patches]
    assert len(bars) == 24
    assert not any(leg.overlaps(b) for b in bars)
    assert [a.get_ylabel() for a in fig.axes] == ["accuracy (touch chirps)", "force RMSE (N)"]
    assert [t.get_text() for t in fig.legends[0].get_texts()] == ["SVM", "network"]


def test_speed_ratio_in_words():
    assert speed_ratio(1.4, 1.0) == "1.4x slower"
    assert speed_ratio(1.0, 2.5) == "2.5x faster"
    assert speed_ratio(1.0, 1.02) == "as fast"


def _options(text: str) -> dict[str, str]:
    """``--option`` -> its help entry (the text after the option spec), from argparse/jsonargparse help."""
    out: dict[str, str] = {}
    cur = None
    for line in text.splitlines():
        m = re.match(r"^  (-{1,2}[\w.\-+]+)(?:[ ,][^ ].*?)?(?:\s{2,}(.*))?$", line)
        if m and not line.startswith("   "):
            cur = m.group(1)
            out[cur] = (m.group(2) or "").strip()
        elif cur and line.startswith(" " * 24):
            out[cur] += " " + line.strip()
        else:
            cur = None
    return out


@pytest.mark.slow
def test_train_help_describes_every_option_with_the_default_train_uses(capsys):
    pytest.importorskip("lightning")
    from sonicskin.cli import main
    from sonicskin.rig import config_dir

    try:
        assert main(["train", "--help"]) in (0, None)
    except SystemExit as e:
        assert e.code in (0, None)
    text = capsys.readouterr().out
    opts = _options(text)
    assert {"--config", "--data", "--model.dropout", "--data.batch_size", "--trainer.max_epochs"} <= set(opts)
    bare = [k for k, v in opts.items() if not re.sub(r"\(type: .*", "", v, flags=re.S).strip()]
    assert not bare, f"options without a description: {bare}"
    # --data means one thing on `sonicskin train`: LightningCLI's --data CONFIG says it is not reachable here.
    assert "dataset folder" in opts["--data"]
    assert text.count("\n  --data CONFIG ") == 1 and "not on `sonicskin train`" in text
    cfg = yaml.safe_load((config_dir() / "train" / "moving.yaml").read_text())
    checked = 0
    for group in ("model", "data"):
        for key, want in cfg[group].items():
            entry = opts[f"--{group}.{key}"]
            shown = re.search(r"default: (.*?)\)$", entry).group(1)
            got = yaml.safe_load(shown.replace("(", "[").replace(")", "]"))
            assert got == want, f"--{group}.{key}: help shows {shown}, train uses {want}"
            checked += 1
    assert checked == len(cfg["model"]) + len(cfg["data"])
    assert re.search(r"default: (\S+)\)$", opts["--trainer.max_epochs"]).group(1) == str(cfg["trainer"]["max_epochs"])
