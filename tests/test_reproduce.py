"""`sonicskin reproduce --quick` end to end: every experiment, both models, every table and figure."""

import json

import pytest

from sonicskin.cli import main


@pytest.mark.slow
def test_quick_reproduction(tmp_path):
    out = tmp_path / "rep"
    assert main(["reproduce", "--quick", "--out", str(out)]) == 0
    md = (out / "report.md").read_text()
    for section in ("Fig. 6b", "Fig. 11", "Fig. 12", "Two months", "Fig. 13", "Table I", "Fig. 14", "Fig. 15", "Fig. 16"):
        assert f"{section}" in md, section
    for fig in ("fig6b", "fig11", "fig12", "fig13", "fig14", "fig15", "fig16"):
        assert (out / f"{fig}.png").stat().st_size > 10_000
    res = json.loads((out / "report.json").read_text())
    # Physical findings that must hold on the simulated rig, whatever the exact numbers:
    assert res["fig6b"]["svm"]["ospa"] > res["fig6b"]["svm"]["all_bins"] + 0.15  # OSPA matters on a moving robot
    assert all(r["svm"]["accuracy"] >= 0.9 for k, r in res["fig16"].items() if "36" not in k)  # two points apart
    assert "net" in res["table1"]["fig14"] and "svm" in res["table1"]["fig15"]
