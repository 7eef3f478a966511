"""The whole arm live: every link of ``configs/arms/arm6.yaml`` (6 links, each its own TX/RX pair) at once, in real
time on the simulated arm, on the ``fast`` rig (13.3 ms chirps) and on the paper's rig (jaco, 106.7 ms).

Per rig: the CPU share of one core that the live loop (all links' framing, features, models, events: the consumer
thread) uses, the simulated device's share beside it (the producer thread; on a robot that is the audio driver's),
per-link chirp-to-event latency p50/p95 (the chirp's last sample available -> its event, as ``latency_ms``), per-link
press-to-event latency p50/p95 (the press's first chirp starts -> the first touch event of that press is out: the chirp
periods it waited plus the processing), dropped and lost blocks, and the share of touch events whose contact point (in
metres, in the link's frame) lies within 1.5 cm of the simulated finger.  From the consumer's share per link: how many
links one such core carries in real time.

Artifacts: one SVM per link and rig, trained once on the simulated arm (``simulate --links`` + ``fit-svm --links``,
cached under ``--work``).  Stdout: the markdown table and the sentences under it; progress on stderr.

    python benchmarks/bench_arm.py [--seconds 20] [--rigs fast jaco] [--work reports/arm-bench]
"""

from __future__ import annotations

import argparse
import sys
import threading
import time
from pathlib import Path

import numpy as np

from sonicskin.acquire import thread_cpu_s
from sonicskin.arm import open_arm
from sonicskin.fit import build_svm_artifact
from sonicskin.links import ARM_FILE, load_links, write_arm
from sonicskin.live import run_loops
from sonicskin.rig import Rig
from sonicskin.sim.generate import simulate_dataset


def _log(msg: str) -> None:
    print(f"bench_arm: {msg}", file=sys.stderr, flush=True)


def train_arm(arm: str, rig: Rig, work: Path) -> Path:
    """The trained arm of ``rig`` under ``work/<rig>`` (its arm.yaml), simulated and fitted once."""
    out = work / rig.name
    if (out / ARM_FILE).is_file():
        return out / ARM_FILE
    links = load_links(arm, rig)
    arts = {}
    for lk in links:
        t0 = time.perf_counter()
        data = work / "data" / rig.name / lk.name
        if not (data / "dataset.json").is_file():
            simulate_dataset(lk.scenario, rig, data, mode="overwrite", progress=False)
        build_svm_artifact(data, out / lk.name, progress=False, log=lambda m: None)
        arts[lk.name] = out / lk.name
        _log(f"{rig.name}: link {lk.name} trained in {time.perf_counter() - t0:.0f} s")
    return write_arm(arm, out, arts, rig)


def press_stats(loop, timeline, rig: Rig, offset: int) -> dict:
    """Press-to-event latencies (ms) and the share of touch events within 1.5 cm of the finger, for one link's loop."""
    L, fs = rig.n_chirp, rig.fs_hz
    first = {}
    near, n_touch = 0, 0
    surf = loop.surface
    for ev in loop.events:
        k = int(round((ev.t_s * fs + offset) / L))  # the timeline chirp the event was computed on
        if not 0 <= k < len(timeline) or ev.kind != "touch":
            continue
        n_touch += 1
        press = int(timeline.event[k])
        if press >= 0:
            finger, _ = surf.point_normal(np.array([[timeline.x_cm[k], timeline.y_cm[k]]]))
            near += float(np.linalg.norm(np.asarray(ev.extra.get("point_m") or ev.to_dict()["point_m"]) - finger[0])) <= 0.015
            if press not in first:
                onset = int(np.flatnonzero(timeline.event == press)[0])
                first[press] = (k - onset + 1) * L / fs * 1e3 + ev.latency_ms
    lat = np.array(list(first.values())) if first else np.full(1, np.nan)
    presses = len(set(timeline.event[timeline.event >= 0].tolist()))
    return {"p50": float(np.median(lat)), "p95": float(np.percentile(lat, 95)), "detected": len(first), "presses": presses,
            "near": near / max(n_touch, 1), "touch_events": n_touch}


def run_arm(arm_file: Path, seconds: float) -> dict:
    """One real-time run of the whole arm; the consumer's and the producer's CPU, per-link figures."""
    run = open_arm(arm_file, fast=False)
    loops = run.loops(emit=lambda line: None)
    src = run.source
    out: dict = {}
    with src:
        c0, w0 = time.thread_time(), time.perf_counter()
        run_loops(loops, src, duration_s=seconds, watchdog_s=10.0)
        consumer, wall = time.thread_time() - c0, time.perf_counter() - w0
        producer = thread_cpu_s(getattr(src, "_thread", None))
    out["consumer_share"] = consumer / wall
    out["producer_share"] = (producer or float("nan")) / wall
    out["wall_s"] = wall
    out["counters"] = src.counters()
    out["relocks"] = sum(lp.framer.relocks for lp in loops)
    out["links"] = {}
    for lp, tl in zip(loops, src.timelines):
        lat = np.asarray(lp.latencies_ms) if lp.latencies_ms else np.full(1, np.nan)
        out["links"][lp.link_name] = {"chirps": lp.n_chirps, "lat_p50": float(np.median(lat)),
                                      "lat_p95": float(np.percentile(lat, 95)), **press_stats(lp, tl, run.rig, src.offset)}
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--arm", default="arm6", help="arm file (default: arm6)")
    ap.add_argument("--rigs", nargs="+", default=["fast", "jaco"], help="rigs to run (default: fast jaco)")
    ap.add_argument("--seconds", type=float, default=20.0, help="seconds of real-time stream per rig (default: 20)")
    ap.add_argument("--work", default="reports/arm-bench", help="cache of the simulated data and artifacts")
    a = ap.parse_args(argv)
    if a.seconds <= 0:
        ap.error("--seconds must be > 0")
    rows = ["| rig (chirp) | links | live loop, share of one core | per link | simulated device | chirp-to-event p50 / p95 "
            "| press-to-event p50 / p95 | presses detected | within 1.5 cm | dropped blocks |",
            "|---|---|---|---|---|---|---|---|---|---|"]
    notes = []
    for name in a.rigs:
        rig = Rig.load(name)
        arm_file = train_arm(a.arm, rig, Path(a.work))
        _log(f"{name}: running {a.seconds:g} s in real time ({threading.active_count()} threads)")
        r = run_arm(arm_file, a.seconds)
        per = r["links"]
        n = len(per)
        worst = lambda k: max(v[k] for v in per.values())  # noqa: E731
        det = sum(v["detected"] for v in per.values())
        pres = sum(v["presses"] for v in per.values())
        near = np.mean([v["near"] for v in per.values()])
        rows.append(f"| {name} ({rig.period_s * 1e3:.1f} ms) | {n} | {r['consumer_share']:.1%} | {r['consumer_share'] / n:.1%} "
                    f"| {r['producer_share']:.1%} | {np.median([v['lat_p50'] for v in per.values()]):.1f} / "
                    f"{worst('lat_p95'):.1f} ms (worst link) | {np.median([v['p50'] for v in per.values()]):.0f} / "
                    f"{worst('p95'):.0f} ms (worst link) | {det} of {pres} | {near:.0%} | "
                    f"{r['counters']['dropped_blocks']} |")
        carried = int(n / max(r["consumer_share"], 1e-9))
        notes.append(f"{name}: one core carries about {carried} links in real time (the live loop at "
                     f"{r['consumer_share'] / n:.1%} of a core per link); per link: " + ", ".join(
                         f"{k} p95 {v['lat_p95']:.1f} ms / press {v['p95']:.0f} ms" for k, v in per.items()))
        _log(f"{name}: {r}")
    print("\n".join(rows))
    print()
    print(f"Real time, {a.seconds:g} s of the simulated {a.arm} per rig, all links at once on one 6-in/6-out interface, on "
          f"this machine ({Path('/proc/cpuinfo').read_text().count('processor')} cores). The live loop is the consumer "
          f"thread (framing, features, Alg. 2, model, events of every link); the simulated device renders the six walls "
          f"in its own thread. Press-to-event counts from the first chirp of a press: the simulator starts presses on "
          f"a chirp boundary, a real finger lands anywhere in a chirp, which adds up to one chirp period (half on average).")
    for x in notes:
        print(f"- {x}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
