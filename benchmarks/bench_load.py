"""The whole arm live on a busy robot PC (issue 37): the six links of ``configs/arms/arm6.yaml`` on the fast rig in
real time for ``--seconds`` beside 0, 2 and 4 busy processes (``python -c "while True: pass"``, another node's
busy loop), each without and with ``--realtime`` (real-time scheduling of the audio and processing threads).

Per run: what the scheduling got, the audio blocks dropped (and the stream seconds they held), the framer's re-locks
over the six links, and the worst link's p95 chirp-to-event latency (``latency_ms``: from the arrival of the block that
completes a chirp to its event, so time waiting in the queue behind a busy loop counts).  Each run is ``sonicskin live
--links ART/arm.yaml`` in a fresh process; the arm is simulated and trained once (``benchmarks/bench_arm.py``'s
``train_arm``, cached under ``--work``).  Stdout: the markdown table and the sentence under it; progress on stderr.

    python benchmarks/bench_load.py [--seconds 60] [--busy 0 2 4] [--work reports/load-bench]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_arm import train_arm  # noqa: E402

from sonicskin.rig import Rig  # noqa: E402

BUSY = "while True: pass"


def _log(msg: str) -> None:
    print(f"bench_load: {msg}", file=sys.stderr, flush=True)


def run_live(arm_file: Path, seconds: float, busy: int, realtime: bool) -> dict:
    """One run of the arm in real time beside ``busy`` busy processes: its summary (what ``sonicskin live`` prints)."""
    hogs = [subprocess.Popen([sys.executable, "-c", BUSY]) for _ in range(busy)]
    try:
        cmd = [sys.executable, "-m", "sonicskin", "live", "--links", str(arm_file), "--duration", f"{seconds:g}",
               "--no-status", "--watchdog", "10"] + (["--realtime"] if realtime else [])
        p = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        load = os.getloadavg()[0]
    finally:
        for h in hogs:
            h.kill()
            h.wait()
    lines = p.stderr.strip().splitlines()
    if p.returncode != 0 or not lines:
        raise SystemExit(f"bench_load: live failed (exit {p.returncode}):\n{p.stderr}")
    for ln in lines[:-1]:
        _log(f"  {ln}")
    out = json.loads(lines[-1])
    out["load"] = load
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--arm", default="arm6", help="arm file (default: arm6)")
    ap.add_argument("--rig", default="fast", help="rig (default: fast, 13.3 ms chirps)")
    ap.add_argument("--seconds", type=float, default=60.0, help="seconds of each real-time run (default: 60)")
    ap.add_argument("--busy", type=int, nargs="+", default=[0, 2, 4], help="busy processes beside it (default: 0 2 4)")
    ap.add_argument("--work", default="reports/load-bench", help="cache of the simulated data and artifacts")
    a = ap.parse_args(argv)
    if a.seconds <= 0 or any(b < 0 for b in a.busy):
        ap.error("--seconds must be > 0 and --busy counts >= 0")
    rig = Rig.load(a.rig)
    arm_file = train_arm(a.arm, rig, Path(a.work))
    rows = ["| busy processes | `--realtime` | scheduling granted (audio / processing thread) | dropped blocks (stream lost) "
            "| re-locks (6 links) | chirp-to-event p95, worst link | load (1-min, at the end) |",
            "|---|---|---|---|---|---|---|"]
    for busy in a.busy:
        for realtime in (False, True):
            _log(f"{busy} busy processes, {'with' if realtime else 'without'} --realtime: {a.seconds:g} s")
            r = run_live(arm_file, a.seconds, busy, realtime)
            links = r["summary"]
            first = next(iter(links.values()))
            granted = r.get("realtime")
            sched = f"{granted['audio']} / {granted['processing']}" if granted else "normal (not asked)"
            p95 = max(s["latency_ms_p95"] for s in links.values())
            rows.append(f"| {busy} | {'yes' if realtime else 'no'} | {sched} | {first['dropped_blocks']} "
                        f"({first['lost_s']:.2f} s) | {sum(s['relocks'] for s in links.values())} | {p95:.1f} ms "
                        f"| {r['load']:.1f} |")
            _log(rows[-1])
    print("\n".join(rows))
    print()
    print(f"{a.seconds:g} s of the simulated {a.arm} ({len(links)} links, each its own TX/RX pair, {rig.name} rig: "
          f"{rig.period_s * 1e3:.1f} ms chirps) in real time per row, `sonicskin live --links` in a fresh process, on this "
          f"machine ({os.cpu_count()} cores), beside that many `python -c \"{BUSY}\"` processes. The queue between the "
          f"audio thread (here the simulated device's) and the loop holds 2 s of audio; a block that does not fit is "
          f"dropped and its stream time named. Chirp-to-event latency counts from the arrival of the block that "
          f"completes the chirp, so time waiting in the queue counts.")
    return 0


if __name__ == "__main__":
    sys.exit(main())
