"""The quick reproduction's findings, checked (what tests/test_reproduce.py checked on every `make test` until issue 37
moved the minutes it takes here; the tests run the same pipeline on tiny datasets).

    sonicskin reproduce --quick --out reports/reproduce-quick     # (the stored result reproduce-quick runs both)
    python benchmarks/check_reproduce.py reports/reproduce-quick   # exit 1 and the failed check on stderr

Checked: every section and figure, the mean and spread over the two simulator seeds, the physical findings that must
hold on the simulated rig whatever the exact numbers (OSPA matters on a moving robot; two points 2 cm or more apart
are told apart, >= 90 %), both models in Table I; then `--only fig13 --seeds 1` on the same datasets runs that
experiment alone.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path


def check(out: Path) -> list[str]:
    """The failed checks of the quick reproduction in ``out`` (empty: every one holds)."""
    bad = []

    def need(ok: bool, what: str) -> None:
        if not ok:
            bad.append(what)

    md = (out / "report.md").read_text()
    for section in ("Fig. 6b", "Fig. 11", "Fig. 12", "Two months", "Fig. 13", "Table I", "Stationary robot, one-shot",
                    "Fig. 14", "Fig. 15", "Fig. 16"):
        need(section in md, f"report.md has no section {section!r}")
    for fig in ("fig6b", "fig11", "fig12", "fig13", "fig14", "fig15", "fig16"):
        need((out / f"{fig}.png").is_file() and (out / f"{fig}.png").stat().st_size > 10_000, f"{fig}.png missing or empty")
    res = json.loads((out / "report.json").read_text())
    need(res["seeds"] == [0, 1], f"seeds {res['seeds']}, not the quick run's [0, 1]")
    acc = res["fig6b"]["svm"]["ospa"]
    need(len(acc["values"]) == 2 and abs(acc["mean"] - sum(acc["values"]) / 2) < 1e-9 and acc["std"] >= 0,
         "Fig. 6b's SVM accuracy is not the mean of its two seeds")
    need("+-" in md.split("## Table I")[1].split("\n## ")[0], "Table I shows no spread over the seeds")
    need(res["fig6b"]["svm"]["ospa"]["mean"] > res["fig6b"]["svm"]["all_bins"]["mean"] + 0.15,
         "OSPA does not matter on the moving robot (Fig. 6b: OSPA not 15 points above every bin)")
    need(all(r["svm"]["accuracy"]["mean"] >= 0.9 for k, r in res["fig16"].items() if "36" not in k),
         "two points apart are not told apart (Fig. 16: an SVM accuracy below 90 %)")
    need("net" in res["table1"]["fig14"] and "svm" in res["table1"]["fig15"] and "svm" in res["table1"]["stationary"],
         "Table I lacks a model")
    with tempfile.TemporaryDirectory() as tmp:
        only = Path(tmp) / "rep"
        only.mkdir()
        (only / "data").symlink_to((out / "data").resolve(), target_is_directory=True)
        p = subprocess.run([sys.executable, "-m", "sonicskin", "reproduce", "--quick", "--only", "fig13", "--seeds", "1",
                            "--out", str(only)], capture_output=True, text=True)
        need(p.returncode == 0, f"reproduce --only fig13 failed: {p.stderr[-500:]}")
        if p.returncode == 0:
            r = json.loads((only / "report.json").read_text())
            need(r["experiments"] == ["fig13"] and r["seeds"] == [1] and "fig6b" not in r, "--only fig13 ran more")
            need(sorted(x.name for x in only.glob("*.png")) == ["fig13.png"], "--only fig13 drew other figures")
    return bad


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("report", type=Path, help="the folder `sonicskin reproduce --quick --out` wrote")
    bad = check(ap.parse_args(argv).report)
    for b in bad:
        print(f"check_reproduce: {b}", file=sys.stderr)
    print(f"check_reproduce: {'every check holds' if not bad else f'{len(bad)} check(s) failed'}", file=sys.stderr)
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
