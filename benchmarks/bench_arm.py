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
import os
import sys
import time
from pathlib import Path

import numpy as np

from sonicskin.acquire import thread_cpu_s
from sonicskin.fit import build_svm_artifact
from sonicskin.links import ARM_FILE, load_links, write_arm
from sonicskin.live import run_loops
from sonicskin.rig import Rig
from sonicskin.session import open_run as open_arm
from sonicskin.sim.generate import simulate_dataset


def _log(msg: str) -> None:
    print(f"bench_arm: {msg}", file=sys.stderr, flush=True)


def train_arm(arm: str, rig: Rig, work: Path, n_bins: int | None = None) -> Path:
    """The trained arm of ``rig`` under ``work/<rig>[-<n_bins>]`` (its arm.yaml), simulated and fitted once; ``n_bins``:
    OSPA's gamma for every link (``fit-svm --n-bins``), ``None``: each link's validation chooses."""
    out = work / (rig.name if n_bins is None else f"{rig.name}-{n_bins}")
    if (out / ARM_FILE).is_file():
        return out / ARM_FILE
    links = load_links(arm, rig)
    arts = {}
    for lk in links:
        t0 = time.perf_counter()
        data = work / "data" / rig.name / lk.name
        if not (data / "dataset.json").is_file():
            simulate_dataset(lk.scenario, rig, data, mode="overwrite", progress=False, log=_log)
        build_svm_artifact(data, out / lk.name, n_bins=n_bins, progress=False, log=lambda m: None)
        arts[lk.name] = out / lk.name
        _log(f"{rig.name}: link {lk.name} trained in {time.perf_counter() - t0:.0f} s")
    return write_arm(arm, out, arts, rig)


def press_stats(loop, timeline, rig: Rig, offset: int, stream_s: float) -> dict:
    """Press-to-event latencies (ms) and the share of touch events within 1.5 cm of the finger, for one link's loop.

    A simulated finger's force rises over about 100 ms (0.02 N one 13 ms chirp after contact, 0.5 N after six); the
    artifact counts a press as a touch from ``min_force_n`` (0.5 N) on.  So two latencies per press: from the first chirp
    of contact, and from the chirp in which the force first reached ``min_force_n`` (negative when the skin saw the press
    before it was that firm)."""
    L, fs = rig.n_chirp, rig.fs_hz
    fmin = float(loop.rt.meta.get("min_force_n", 0.0))
    first, firm = {}, {}
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
            near += float(np.linalg.norm(np.asarray(ev.point_m) - finger[0])) <= 0.015
            if press not in first:
                rows = np.flatnonzero(timeline.event == press)
                onset = int(rows[0])
                first[press] = (k - onset + 1) * L / fs * 1e3 + ev.latency_ms
                firm_rows = rows[timeline.force_n[rows] >= fmin]
                if firm_rows.size:
                    firm[press] = (k - int(firm_rows[0])) * L / fs * 1e3 + ev.latency_ms
    played = int(stream_s * fs - offset) // L - 1  # the chirps the stream held whole
    ids = timeline.event[:played]
    cut = int(timeline.event[played - 1])
    presses = len(set(ids[ids >= 0].tolist()) - {cut})  # the last press may be cut: not counted
    first = {k: v for k, v in first.items() if k != cut}
    lat = np.array(list(first.values())) if first else np.full(1, np.nan)
    lat_firm = np.array([v for k, v in firm.items() if k != cut]) if firm else np.full(1, np.nan)
    return {"p50": float(np.median(lat)), "p95": float(np.percentile(lat, 95)), "firm_p50": float(np.median(lat_firm)),
            "firm_p95": float(np.percentile(lat_firm, 95)), "detected": len(first), "presses": presses,
            "near": near / max(n_touch, 1), "touch_events": n_touch, "min_force_n": fmin}


def run_arm(arm_file: Path, seconds: float, realtime: bool) -> dict:
    """One run of the whole arm, in real time or as fast as it goes; the live loop's (consumer thread's) CPU per second
    of stream, the simulated device's, per-link figures."""
    run = open_arm(arm_file, fast=not realtime)
    loops = run.loops(emit=lambda line: None)
    src = run.source
    out: dict = {}
    with src:
        c0, w0 = time.thread_time(), time.perf_counter()
        sums = run_loops(loops, src, duration_s=seconds, watchdog_s=10.0)
        consumer, wall = time.thread_time() - c0, time.perf_counter() - w0
        producer = thread_cpu_s(getattr(src, "_thread", None))
    stream_s = max(x["stream_s"] for x in sums)
    out["consumer_share"] = consumer / stream_s  # what real time asks of one core
    out["producer_share"] = (producer or float("nan")) / stream_s
    out["wall_s"], out["stream_s"] = wall, stream_s
    out["counters"] = src.counters()
    out["relocks"] = sum(lp.framer.relocks for lp in loops)
    out["links"] = {}
    for lp, tl in zip(loops, src.timelines):
        lat = np.asarray(lp.latencies_ms) if lp.latencies_ms else np.full(1, np.nan)
        out["links"][lp.link_name] = {"chirps": lp.n_chirps, "lat_p50": float(np.median(lat)),
                                      "lat_p95": float(np.percentile(lat, 95)),
                                      **press_stats(lp, tl, run.rig, src.offset, stream_s)}
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
    rows = ["| rig (chirp) | models | live loop, share of one core (per link) | simulated device | chirp-to-event p50 / p95 "
            "| press-to-event from contact, p50 / p95 | from 0.5 N, p50 / p95 | presses detected | within 1.5 cm "
            "| dropped blocks (real time) |",
            "|---|---|---|---|---|---|---|---|---|---|"]
    notes = []
    runs = [(name, nb) for name in a.rigs for nb in ([None, 300] if Rig.load(name).period_s < 0.05 else [None])]
    for name, n_bins in runs:
        rig = Rig.load(name)
        arm_file = train_arm(a.arm, rig, Path(a.work), n_bins)
        what = "validated gamma" if n_bins is None else f"gamma {n_bins} (paper)"
        _log(f"{name}, {what}: running {a.seconds:g} s as fast as it runs, then in real time")
        r = run_arm(arm_file, a.seconds, realtime=False)
        _log(f"{name}: as fast as it runs: {r}")
        rt = run_arm(arm_file, a.seconds, realtime=True)
        _log(f"{name}: real time: {rt}")
        per = r["links"]
        n = len(per)

        def worst(k, per=per):
            return max(v[k] for v in per.values())

        def median(k, per=per):
            return float(np.median([v[k] for v in per.values()]))

        det = sum(v["detected"] for v in per.values())
        pres = sum(v["presses"] for v in per.values())
        near = np.mean([v["near"] for v in per.values()])
        rows.append(f"| {name} ({rig.period_s * 1e3:.1f} ms) | SVM, {what} | {r['consumer_share']:.1%} "
                    f"({r['consumer_share'] / n:.1%}) | {r['producer_share']:.1%} | {median('lat_p50'):.1f} / "
                    f"{worst('lat_p95'):.1f} ms | {median('p50'):.0f} / {worst('p95'):.0f} ms | {median('firm_p50'):.0f} / "
                    f"{worst('firm_p95'):.0f} ms | {det} of {pres} | {near:.0%} | {rt['counters']['dropped_blocks']} |")
        carried = int(n / max(r["consumer_share"], 1e-9))
        gammas = {k: len(rtm.spec.bins) for k, rtm in zip(per, open_arm(arm_file).runtimes)}
        notes.append(f"{name}, {what} ({', '.join(f'{k} {g}' for k, g in gammas.items())} bins): one core carries about "
                     f"{carried} such links in real time; per link chirp-to-event p95 / from-0.5-N p95: " + ", ".join(
                         f"{k} {v['lat_p95']:.1f} / {v['firm_p95']:.0f} ms" for k, v in per.items())
                     + f"; in real time ({rt['wall_s']:.0f} s, load {os.getloadavg()[0]:.1f}) the live loop used "
                     f"{rt['consumer_share']:.1%} of a core, the simulated device {rt['producer_share']:.1%}, "
                     f"{rt['counters']['dropped_blocks']} blocks dropped, {rt['relocks']} re-locks")
    print("\n".join(rows))
    print()
    print(f"{a.seconds:g} s of the simulated {a.arm} per rig, all links at once on one 6-in/6-out interface, on this "
          f"machine ({os.cpu_count()} cores), as fast as it runs (the shares are CPU seconds per second of stream: what "
          f"real time asks of one core), then once in real time for the dropped blocks. The live loop is the consumer "
          f"thread (framing, features, Alg. 2, model, events of every link); the simulated device renders the six walls "
          f"in its own thread (on a robot: the audio driver). Press-to-event: from the press's first chirp of contact (the "
          f"simulated finger's force rises over about 100 ms: 0.02 N one fast chirp in, 0.5 N six chirps in), and from the "
          f"chirp in which it first reached the artifacts' min_force_n of 0.5 N, the lightest press they count as a touch "
          f"(negative: seen before it was that firm); the simulator starts presses on a chirp boundary, a real finger lands "
          f"anywhere in a chirp, which adds up to one chirp period (half on average).")
    for x in notes:
        print(f"- {x}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
