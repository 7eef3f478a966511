"""The bring-up sequence on the simulated device, with what each step printed: check, record (which writes the
deployable artifact), live.

In a temporary folder (the commands as the README shows them, run with this Python's ``sonicskin``):

1. ``sonicskin check --out check``: the rig check's table (shown in full below the table);
2. ``sonicskin record --out data/my-robot --artifact artifacts/my-robot --device sim --scenario stationary --fast
   --moving-s 0`` (three passes over the markers, then the artifact ``fit-svm`` would write);
3. live: ``sonicskin.Listener("artifacts/my-robot", scenario="stationary", fast=True)`` on a new simulated
   session of the same link (seed + 1000, as ``sonicskin live``), every chirp scored against the
   session's script (:func:`sonicskin.sim.build_timeline`): localization of the touch events on pressed
   chirps (force >= 0.5 N), their mean position error against where the finger really was, false touches
   on hands-off chirps, missed pressed chirps, the latency median.  One session, one seed.

Stdout: a markdown table (step | command | wall time | result) and the check's table as a text
block; every command's own output goes to stderr.  Everything is seeded (the scenario's seeds).

    python benchmarks/bringup.py [--small]
"""

from __future__ import annotations

import argparse
import shlex
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import sonicskin

REPO = Path(__file__).resolve().parents[1]
PRESSED_N = 0.5  # a pressed chirp, as `fit-svm` and `record --resume` count them


def sonicskin_cmd(args: str, cwd: Path) -> tuple[float, str, str]:
    """Run ``sonicskin ARGS`` in ``cwd``: (wall s, stdout, stderr); its output is echoed to stderr."""
    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, "-m", "sonicskin", *shlex.split(args)], cwd=cwd, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    print(f"$ sonicskin {args}\n{p.stdout}{p.stderr}", file=sys.stderr)
    if p.returncode != 0:
        raise SystemExit(f"bringup: `sonicskin {args}` failed (exit {p.returncode}): {p.stderr.strip()[-500:]}")
    return wall, p.stdout, p.stderr


def last_line(text: str, word: str) -> str:
    hits = [x.strip() for x in text.splitlines() if word in x]
    if not hits:
        raise SystemExit(f"bringup: no line with {word!r} in:\n{text}")
    return hits[-1]


def score_live(artifact: Path, scenario: str, rig: str | None) -> tuple[float, dict]:
    """One simulated live session through :class:`sonicskin.Listener`, scored chirp by chirp against its script."""
    t0 = time.perf_counter()
    lst = sonicskin.Listener(artifact, scenario=scenario, rig=rig, fast=True)
    src = lst.source
    L = src.rig.n_chirp
    chirps: list[tuple[int, bool]] = []  # (timeline row, predicted after the boot calibration)
    lst.loop.on_chirp = lambda t_s, p: chirps.append((int(round((t_s * src.rig.fs_hz + src.offset) / L)), p is not None))
    events = list(lst)
    wall = time.perf_counter() - t0
    tl = src.timeline
    rows = np.array([k for k, pred in chirps if pred])
    if rows.size == 0 or rows.max() >= len(tl):
        raise SystemExit(f"bringup: {len(chirps)} chirps framed, none matches the script's {len(tl)}")
    force = tl.force_n[rows]
    pressed, rest = rows[force >= PRESSED_N], rows[force == 0]
    touch = [e for e in events if e.kind == "touch"]
    k_ev = np.array([int(round((e.t_s * src.rig.fs_hz + src.offset) / L)) for e in touch], int)
    on_pressed = np.isin(k_ev, pressed)
    hit = np.array([e.location for e in touch])[on_pressed] == tl.location[k_ev[on_pressed]]
    err = np.hypot(np.array([e.x_cm for e in touch])[on_pressed] - tl.x_cm[k_ev[on_pressed]],
                   np.array([e.y_cm for e in touch])[on_pressed] - tl.y_cm[k_ev[on_pressed]])
    xy = lst.runtime.layout.xy_cm
    d = np.hypot(*(xy[:, None, :] - xy[None, :, :]).transpose(2, 0, 1))
    return wall, {"chirps": len(chirps), "presses": int(len(np.unique(tl.event[tl.event >= 0]))),
                  "touch_events_pressed": int(on_pressed.sum()), "localization": float(hit.mean()),
                  "position_error_cm": float(err.mean()), "spacing_cm": float(d[d > 0].min()),
                  "false_touch": float(np.isin(k_ev, rest).sum() / max(rest.size, 1)), "rest_chirps": int(rest.size),
                  "missed": float(1 - np.isin(pressed, k_ev).mean()), "pressed_chirps": int(pressed.size),
                  "latency_ms_median": float(lst.summary["latency_ms_median"])}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                 epilog="Stdout: the markdown table and the check's text block only; the commands' output on stderr.")
    ap.add_argument("--small", action="store_true", help="the tests' small rig (1024-sample chirps) and 3-marker plate, "
                    "short presses: seconds, for the tests")
    a = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="bringup-") as tmp:
        cwd = Path(tmp)
        scenario, rig, opt, rec, chk = "stationary", None, "", "", ""
        if a.small:
            sys.path.insert(0, str(REPO / "tests"))
            from cli_helpers import SMALL_RIG, TINY_SCENARIO

            (cwd / "small.yaml").write_text(SMALL_RIG)
            (cwd / "tiny.yaml").write_text(TINY_SCENARIO)
            scenario, rig, opt = "tiny.yaml", "small.yaml", " --rig small.yaml"
            chk, rec = " --scenario tiny.yaml --rest 3 --press 1", " --touch-s 1 --gap-s 0.3"
        steps = []
        wall, check_out, _ = sonicskin_cmd(f"check --out check{opt}{chk}", cwd)
        steps.append(("1. check", f"sonicskin check --out check{opt}{chk}", wall, last_line(check_out, "rig check:")))
        cmd = (f"record --out data/my-robot --artifact artifacts/my-robot --device sim --scenario {scenario}{opt} --fast "
               f"--moving-s 0{rec}")
        wall, out, err = sonicskin_cmd(cmd, cwd)
        steps.append(("2. record", f"sonicskin {cmd}", wall,
                      f"{last_line(out, ' chirps in ')}; {last_line(out, 'chose gamma')}; {last_line(out, 'svm.onnx')}"
                      .replace(tmp + "/", "")))
        print(f"live: Listener on {scenario}, scored against the script", file=sys.stderr)
        wall, s = score_live(cwd / "artifacts" / "my-robot", str(cwd / scenario) if a.small else scenario,
                             str(cwd / rig) if rig else None)
        print(f"live: {s}", file=sys.stderr)
    live = (f"{s['chirps']} chirps, {s['presses']} presses; localization {s['localization']:.1%} of the "
            f"{s['touch_events_pressed']} touch events on pressed chirps (markers {s['spacing_cm']:.1f} cm apart), mean position "
            f"error {s['position_error_cm']:.2f} cm; false touches {s['false_touch']:.1%} of the {s['rest_chirps']} hands-off chirps; "
            f"missed {s['missed']:.1%} of the {s['pressed_chirps']} pressed chirps (>= {PRESSED_N:g} N); latency median "
            f"{s['latency_ms_median']:.2f} ms per chirp")
    steps.append(("3. live", f'sonicskin.Listener("artifacts/my-robot", scenario="{scenario}", '
                  f'fast=True), scored against the script', wall, live))
    out = ["| step | command | wall time | result |", "|---|---|---|---|"]
    out += [f"| {name} | `{cmd}` | {wall:.0f} s | {res.replace('|', chr(92) + '|')} |" for name, cmd, wall, res in steps]
    out += ["", "The check (step 1) printed:", "", "```text", check_out.rstrip("\n"), "```"]
    print("\n".join(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
