"""Live consumer cost per chirp (median, p99) for the SVM and the network, how many links (TX/RX pairs)
one core sustains, the CPU share in real time, and what a stream with lost blocks does.

- Per chirp: :class:`sonicskin.live.LiveLoop` on the simulated moving robot (a new session, seed 99),
  as fast as it runs, once per model; a short real-time run per model gives the process's CPU share
  (the simulated device included).
- Fault injection: ``sonicskin live --fast --drop-every 100 --duration 60`` (the command itself) and the
  same run without drops; its summary (stderr JSON) gives overflows, re-locks, chirps and touch events.

Without ``--artifact`` both models are trained on the simulated moving robot first
(``bench_models.build_artifact``, cached under ``--work``).  Stdout: the markdown table and two
sentences; everything else goes to stderr.

    python benchmarks/bench_live.py [--artifact DIR] [--seconds 20] [--realtime-s 10] [--fault-s 60] [--small]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml
from bench_models import _log, build_artifact

from sonicskin.acquire import SimulatedSource
from sonicskin.live import LiveLoop
from sonicskin.rig import Rig
from sonicskin.runtime import SkinRuntime
from sonicskin.sim import Scenario, Simulator, build_timeline


def run(artifact: Path, model: str, rig: Rig, realtime: bool, seconds: float) -> dict:
    sc = Scenario.load("moving").replace(seed=99, sessions=1)
    tl = build_timeline(sc, rig)
    tl = tl.select(np.arange(len(tl)) < int(seconds * rig.chirps_per_s))
    src = SimulatedSource(Simulator(sc, rig), tl, realtime=realtime)
    loop = LiveLoop(SkinRuntime(artifact, model, rig=rig), src, emit=lambda _: None)
    with src:
        return loop.run()


def live_cli(artifact: Path, rig_yaml: Path, seconds: float, drop_every: int | None) -> dict:
    """``sonicskin live`` on the simulated moving robot, --fast; its summary."""
    cmd = [sys.executable, "-m", "sonicskin", "live", "--artifact", str(artifact), "--scenario", "moving", "--rig", str(rig_yaml),
           "--fast", "--duration", f"{seconds:g}", "--no-status"] + (["--drop-every", str(drop_every)] if drop_every else [])
    p = subprocess.run(cmd, capture_output=True, text=True)
    lines = [x for x in p.stderr.splitlines() if x.startswith('{"summary"')]
    if p.returncode != 0 or not lines:
        raise SystemExit(f"bench_live: `sonicskin {' '.join(cmd[3:])}` failed (exit {p.returncode}): {p.stderr.strip()[-500:]}")
    print(p.stderr, file=sys.stderr, end="")
    return json.loads(lines[-1])["summary"]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                 epilog="Stdout: the markdown table and two sentences only; progress on stderr.")
    ap.add_argument("--artifact", help="artifact with net and svm on the jaco rig (default: train one, bench_models.build_artifact)")
    ap.add_argument("--work", default="reports/bench-models", help="where the default artifact and its data go "
                    "(default: reports/bench-models, shared with bench_models.py; with --small: a temporary folder)")
    ap.add_argument("--seconds", type=float, default=20.0, help="seconds of stream timed per model (default: 20)")
    ap.add_argument("--realtime-s", type=float, default=10.0, help="seconds of real-time stream per model for the CPU share (default: 10)")
    ap.add_argument("--fault-s", type=float, default=60.0, help="seconds of stream of the fault-injection runs (default: 60)")
    ap.add_argument("--drop-every", type=int, default=100, help="drop one audio block in N (default: 100)")
    ap.add_argument("--small", action="store_true", help="a short-chirp rig and a few seconds of stream: for the tests")
    a = ap.parse_args(argv)
    if min(a.seconds, a.realtime_s, a.fault_s) <= 0 or a.drop_every < 2:
        ap.error("--seconds, --realtime-s and --fault-s must be > 0 and --drop-every >= 2")
    if a.small:
        a.seconds, a.realtime_s, a.fault_s = min(a.seconds, 6.0), min(a.realtime_s, 2.0), min(a.fault_s, 12.0)
    with tempfile.TemporaryDirectory(prefix="bench-live-") as tmp:
        if a.artifact:
            art = Path(a.artifact)
            if not (art / "skin.json").is_file():
                raise SystemExit(f"bench_live: {art} is not a sonicskin artifact (no skin.json there); leave out --artifact "
                                 f"to train one")
            rig = SkinRuntime(art, "svm").rig
        else:
            art, ds = build_artifact(Path(tmp) if a.small and a.work == ap.get_default("work") else Path(a.work), small=a.small)
            rig = ds.rig
        rig_yaml = Path(tmp) / "rig.yaml"
        rig_yaml.write_text(yaml.safe_dump(rig.to_dict()))
        period_ms = rig.period_s * 1e3
        _log(f"threads: OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', 'unset')}; chirp period {period_ms:.1f} ms; artifact {art}")
        out = [f"| model | per chirp median | p99 | share of the {period_ms:.1f} ms period (p99) | links one core sustains |",
               "|---|---|---|---|---|"]
        cpu = {}
        for model, name in (("svm", "SVM"), ("net", "network")):
            s = run(art, model, rig, realtime=False, seconds=a.seconds)
            _log(f"{model}: {s['chirps']} chirps as fast as they run: {s}")
            out.append(f"| {name} | {s['latency_ms_median']:.2f} ms | {s['latency_ms_p99']:.2f} ms "
                       f"| {s['latency_ms_p99'] / period_ms:.1%} | ~{int(period_ms // s['latency_ms_median'])} |")
            t0 = time.perf_counter()
            r = run(art, model, rig, realtime=True, seconds=a.realtime_s)
            _log(f"{model}: real time, {r['chirps']} chirps in {time.perf_counter() - t0:.1f} s: {r}")
            cpu[name] = r["cpu_share"]
        clean = live_cli(art, rig_yaml, a.fault_s, None)
        drop = live_cli(art, rig_yaml, a.fault_s, a.drop_every)
    out += ["", f"Per chirp: {a.seconds:g} s of the simulated moving robot per model, as fast as it runs, "
            f"OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', 'unset')}. In real time ({a.realtime_s:g} s) the whole process "
            f"(simulated device included) uses " + " / ".join(f"{v:.1%}" for v in cpu.values()) + " of one core (SVM / network)."]
    out += ["", f"Fault injection, {a.fault_s:g} s of stream, one block in {a.drop_every} dropped (`sonicskin live --fast "
            f"--drop-every {a.drop_every}`, SVM): {drop['overflows']} overflows, {drop['relocks']} re-locks, {drop['chirps']} chirps "
            f"processed ({clean['chirps']} without drops), {drop['touch_events']} touch events ({clean['touch_events']}), no crash."]
    print("\n".join(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
