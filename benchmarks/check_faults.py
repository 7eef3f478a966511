"""What `sonicskin check` says for each simulated fault: the line that fails, as measured, and its fix.

Runs ``sonicskin check --sim-fault NAME --out DIR`` (the command itself, in a temporary folder) for
every fault the simulated device knows (:data:`sonicskin.check.FAULTS`) and reads each run's
``check.json``: the failed line's name, measured value and fix, plus any line that warns.  Stdout: a
markdown table, one row per fault (and a first row for the healthy rig); progress on stderr.

    python benchmarks/check_faults.py [--rest 4] [--press 3] [--small]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

from sonicskin.check import FAULTS

# What each injected fault stands for on a real rig (the injection itself: sonicskin.check.SimulatedDevice).
WHAT = {"none": "healthy rig", "disconnected": "output not connected", "wrong-channel": "receiver on another input",
        "clipping": "input gain 40 x too high", "rate": "a rate the device does not run", "weak": "chirp 40 dB too weak"}


def run_check(fault: str, out: Path, rest: float, press: float) -> tuple[int, dict]:
    cmd = [sys.executable, "-m", "sonicskin", "check", "--out", str(out), "--rest", f"{rest:g}", "--press", f"{press:g}",
           "--sim-fault", fault]
    p = subprocess.run(cmd, capture_output=True, text=True)
    if p.returncode not in (0, 1) or not (out / "check.json").is_file():
        raise SystemExit(f"check_faults: `{' '.join(cmd[2:])}` failed (exit {p.returncode}): {p.stderr.strip()[-500:]}")
    print(p.stdout, file=sys.stderr)
    return p.returncode, json.loads((out / "check.json").read_text())


def row(fault: str, code: int, doc: dict) -> str:
    fail = [x for x in doc["lines"] if x["status"] == "fail"]
    warn = [x for x in doc["lines"] if x["status"] == "warn"]
    if (code == 0) != (not fail) or doc["ok"] != (not fail):
        raise SystemExit(f"check_faults: fault {fault}: exit code {code}, ok {doc['ok']} and {len(fail)} failed lines disagree")
    what = f"{WHAT.get(fault, fault)} (`{fault}`)"
    if not fail:
        return f"| {what} | none: all {len(doc['lines'])} lines pass ({len(warn)} warn), exit {code} | - |"
    measured = ("" if len(fail) == 1 else f"{len(fail)} lines fail: ") + "; ".join(f"{x['name']}: {x['value']}" for x in fail)
    if warn:
        measured += " (warns: " + "; ".join(f"{x['name']} {x['value']}" for x in warn) + ")"
    skipped = sum(x["status"] == "skip" for x in doc["lines"])
    measured += f"; {skipped} line{'s' * (skipped != 1)} skipped, exit {code}"
    return f"| {what} | {measured} | {' / '.join(x['fix'] for x in fail)} |"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                 epilog="Stdout: the markdown table only; each check's own table goes to stderr.")
    ap.add_argument("--rest", type=float, default=4.0, help="seconds hands off per check (default: 4, the check's own)")
    ap.add_argument("--press", type=float, default=3.0, help="seconds of the scripted press (default: 3)")
    ap.add_argument("--small", action="store_true", help="short checks (3 s rest, 1 s press): for the tests")
    a = ap.parse_args(argv)
    rest, press = (3.0, 1.0) if a.small else (a.rest, a.press)
    out = ["| fault | the line that fails (measured) | its fix |", "|---|---|---|"]
    with tempfile.TemporaryDirectory(prefix="check-faults-") as tmp:
        for fault in FAULTS:
            print(f"check_faults: sonicskin check --sim-fault {fault}", file=sys.stderr)
            code, doc = run_check(fault, Path(tmp) / fault, rest, press)
            out.append(row(fault, code, doc))
    print("\n".join(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
