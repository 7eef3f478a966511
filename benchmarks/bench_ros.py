"""Touch on the robot's own bus, measured on the simulated arm6 as docs/arm.md documents it (issue 35).

Trains arm6 with the documented commands (``simulate --links arm6``, ``fit-svm --links arm6 --n-bins 300``, cached
under ``--work``), then runs ``live --links ART/arm.yaml --fast`` with ``--mcap``:

* 20 s, the documented run: the MCAP file's size, chunks and messages; per link, the Contact messages a second while
  touched and while not (stream time), the longest gap between two, and what was published of the wrench;
* ``--long`` s (default 300): the size again, for the size of an hour;
* a run killed with SIGKILL once it printed an event past 10 s: ``python -m sonicskin.rosbag`` recovers the file;
  how many of the printed events' points it holds, and how much stream before the last printed event is lost.

Stdout: the markdown table and the sentences under it; progress on stderr.

    python benchmarks/bench_ros.py [--work reports/ros-bench] [--long 300]
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

from sonicskin.links import load_links
from sonicskin.rig import Rig


def _log(msg: str) -> None:
    print(f"bench_ros: {msg}", file=sys.stderr, flush=True)


def sonicskin(*args, **kw) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "sonicskin", *map(str, args)], check=True, **kw)


def messages(path: Path) -> list:
    with open(path, "rb") as f:
        return [(c.topic, m.log_time, r) for _, c, m, r in make_reader(f, decoder_factories=[DecoderFactory()]).iter_decoded_messages()]


def run(arm: Path, seconds: float, out: Path) -> list:
    out.unlink(missing_ok=True)
    sonicskin("live", "--links", arm, "--fast", "--duration", seconds, "--no-status", "--mcap", out,
              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return messages(out)


def killed(arm: Path, work: Path) -> tuple[int, int, int, float]:
    """Killed at its first event past 10 s: (events printed, those more than a second older than the last, their points
    recovered, the stream between the newest recovered message and the last printed event)."""
    path, fixed = work / "killed.mcap", work / "fixed.mcap"
    path.unlink(missing_ok=True)
    child = subprocess.Popen([sys.executable, "-m", "sonicskin", "live", "--links", str(arm), "--fast", "--duration", "600",
                              "--no-status", "--mcap", str(path)], stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    printed = []
    for line in child.stdout:
        printed.append(json.loads(line))
        if printed[-1]["t_s"] > 10.0:
            os.kill(child.pid, signal.SIGKILL)
            break
    printed += [json.loads(x) for x in child.stdout.read().splitlines() if x.endswith("}")]
    child.wait()
    subprocess.run([sys.executable, "-m", "sonicskin.rosbag", str(path), str(fixed)], check=True, stdout=subprocess.DEVNULL)
    msgs = messages(fixed)
    t0 = next(t for topic, t, _ in msgs if topic == "/robot_description")
    points = defaultdict(list)
    for topic, t, m in msgs:
        if topic.endswith("/contact_point"):
            points[m.header.frame_id].append((t - t0) / 1e9)
    last = max(e["t_s"] for e in printed)
    older = [e for e in printed if e["t_s"] <= last - 1.0]
    held = sum(bool(points[e["frame_id"]]) and min(abs(np.asarray(points[e["frame_id"]]) - e["t_s"])) < 1e-4 for e in older)
    return len(printed), len(older), held, last - (max(t for _, t, _ in msgs) - t0) / 1e9


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work", default="reports/ros-bench", help="the trained arm and the runs' files")
    ap.add_argument("--long", type=float, default=300.0, help="stream seconds of the long run (the size of an hour)")
    a = ap.parse_args()
    work = Path(a.work)
    arm = work / "art" / "arm.yaml"
    if not arm.is_file():
        _log("training arm6 (simulate, fit-svm)")
        sonicskin("simulate", "--links", "arm6", "--out", work / "data", "--quiet", stdout=subprocess.DEVNULL)
        sonicskin("fit-svm", "--links", "arm6", "--data", work / "data", "--out", work / "art", "--n-bins", 300,
                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    _log("20 s")
    short = run(arm, 20, work / "arm.mcap")
    size20 = (work / "arm.mcap").stat().st_size
    with open(work / "arm.mcap", "rb") as f:
        chunks = make_reader(f).get_summary().statistics.chunk_count
    _log(f"{a.long:g} s")
    long = run(arm, a.long, work / "long.mcap")
    size_long, span_long = (work / "long.mcap").stat().st_size, (long[-1][1] - long[0][1]) / 1e9  # the scripts may end first
    _log("killed")
    n_printed, n_older, n_held, lost_s = killed(arm, work)
    rows = ["| link (frame) | Contact/s touched | Contact/s untouched | longest gap | events/s | wrenches/s | force |",
            "|---|---|---|---|---|---|---|"]
    shares = []
    for frame in [lk.surface.frame_id for lk in load_links(arm, Rig.load("fast"))]:
        c = [(t, m) for topic, t, m in short if topic == f"/sonicskin/{frame}/contact"]
        ts = np.array([t for t, _ in c]) / 1e9
        touched = np.array([m.touched for _, m in c])
        dt = np.diff(ts)
        t_touched = dt[touched[:-1]].sum()  # stream time spent touched (each message until the next)
        n_ev = sum(topic == f"/sonicskin/{frame}/contact_point" for topic, _, _ in short)
        n_wr = sum(topic == f"/sonicskin/{frame}/contact_wrench" for topic, _, _ in short)
        span = ts[-1] - ts[0]
        shares.append(t_touched / span)
        rows.append(f"| {c[0][1].link} ({frame}) | {touched[:-1].sum() / t_touched:.1f} | "
                    f"{(~touched[:-1]).sum() / (span - t_touched):.1f} | {dt.max() * 1e3:.1f} ms | {n_ev / span:.1f} | "
                    f"{n_wr / span:.1f} | {'reliable' if c[-1][1].force_reliable else 'unreliable: no wrench'} |")
    print("\n".join(rows))
    print()
    hour = size_long / span_long * 3600
    print(f"`live --links ART/arm.yaml --fast --duration 20 --mcap arm.mcap` on arm6 (fit-svm --n-bins 300): "
          f"{size20 / 1e6:.2f} MB in {chunks} zstd chunks for {len(short):,} messages; a longer run ({span_long:.0f} s of stream, "
          f"to the end of the links' scripted presses): {size_long / 1e6:.1f} MB, "
          f"so about {hour / 1e6:.0f} MB an hour at this rate of presses (the scripted presses keep each link touched "
          f"{100 * np.mean(shares):.0f} % of the time; an idle arm writes its six Contacts at 18.75 Hz and little else). "
          f"Killed with SIGKILL after an event past 10 s of stream: the run had printed {n_printed} events, and `python -m "
          f"sonicskin.rosbag` recovered the points of {n_held} of the {n_older} that came more than a second before the "
          f"last; the newest message recovered is {lost_s:.2f} s of stream older than the last printed event.")


if __name__ == "__main__":
    main()
