"""The verbs on a device, simulated or real: ``live``, ``record`` and ``check``."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from ..acquire import DeviceLost, check_blocksize, exit_unhung
from ..check import analyse, capture
from ..errors import UsageError
from ..jsonio import json_safe
from ..links import load_arm
from ..live import LslSink, UdpSink
from ..record import record_session, train_oneshot
from ..rig import Rig
from ..session import open_run, simulated
from ..sim import Scenario
from ._common import clean_on_failure, writer_mode


def _stdout_sink(line: str) -> None:
    """One event line to stdout; a write that fails (a full disk, /dev/full) is one line naming where events went."""
    try:
        print(line, flush=True)
    except BrokenPipeError:  # `sonicskin live | head`: the reader went away (main() ends quietly)
        raise
    except OSError as e:
        raise UsageError(f"cannot write the touch events to stdout ({e.strerror or e}): the file or device it goes to "
                         f"is full or gone; write them where there is room (`sonicskin live ... > events.jsonl`)") from None


def cmd_live(a: argparse.Namespace) -> int:
    """One link (``--artifact``) or several (``--links``); without an artifact a simulated link is trained on the spot, once."""

    check_blocksize(a.blocksize, "--blocksize")
    if a.lsl is not None and not a.lsl.strip():  # an LSL stream with an empty name cannot be found by any inlet
        raise UsageError(f"--lsl {a.lsl!r}: the stream needs a name (e.g. --lsl sonicskin, or --lsl alone for that "
                         f"default)")
    sim = simulated(a.device)
    if a.drop_every is not None and not sim:
        raise UsageError("--drop-every injects lost blocks into the simulated device (--device sim); a real device "
                         "loses its own")
    if a.drop_every == 1:
        raise UsageError("--drop-every 1 drops every audio block, so nothing would reach the loop; give N >= 2 "
                         "(one block lost in N)")
    if not a.links and a.artifact is None and a.model is not None:
        raise UsageError(f"--model {a.model} needs an artifact that holds it (the network: `sonicskin train`, then "
                         f"`sonicskin export --run RUN --out DIR`, then --artifact DIR); without --artifact the paper's "
                         f"SVM is trained on the spot")
    if not a.links and a.artifact is None and not sim:
        raise UsageError("a real rig needs a model trained on it: `sonicskin record --out DIR` (it writes DIR-artifact "
                         "when it finishes), then `sonicskin live --device ... --artifact DIR-artifact`")
    if not a.links and sim and (a.tx or a.rx):  # were ignored
        raise UsageError("--tx/--rx choose the channels of a real interface (--device NAME|INDEX); the simulated "
                         "device has one link: drop them")
    if sys.stdout is None and not (a.udp or a.lsl):  # started with stdout closed (`>&-`): print() drops every event
        raise UsageError("stdout is closed, so the touch events would go nowhere; send them to a file or a pipe "
                         "(`sonicskin live ... > events.jsonl`), or add --udp/--lsl")
    sinks = [_stdout_sink]
    if a.udp:
        sinks.append(UdpSink(f"{a.udp[0]}:{a.udp[1]}"))  # resolved here: a bad host is one line before the run
    if a.lsl:
        sinks.append(LslSink(a.lsl))
    run = open_run(a.artifact, links=a.links, device=a.device, model=a.model, scenario=a.scenario, rig=a.rig, tx=a.tx,
                   rx=a.rx, fast=a.fast, blocksize=a.blocksize, drop_every=a.drop_every, link_artifacts=a.link_artifact,
                   train=train_oneshot, mcap=a.mcap, overwrite=a.overwrite, realtime=a.realtime, ros2=a.ros2,
                   foxglove=a.foxglove, duration_s=a.duration)
    loops = run.loops(emit=lambda line: [s(line) for s in sinks], status=not a.no_status, view=a.view)
    if run.view is not None:
        print(f"sonicskin live: the live view is at {run.view.url} (open it in a browser on this machine)", file=sys.stderr, flush=True)
    for bus in run.buses:
        print(f"sonicskin live: {bus.kind} is on {bus.name}", file=sys.stderr, flush=True)
    lost = None
    try:
        summary = run.run(duration_s=a.duration, watchdog_s=a.watchdog)
    except DeviceLost as e:
        lost, summary = e, run.summary([lp.summary(0.0, 0.0, 0.0) for lp in loops])
    out = {"summary": json_safe(summary)}
    if run.granted:
        out["realtime"] = run.granted
    if run.mcap is not None:
        out["mcap"] = {"path": str(a.mcap), "events": run.mcap.written, "messages": run.mcap.messages}
    print(json.dumps(out, allow_nan=False), file=sys.stderr)
    if lost is not None:
        raise lost
    exit_unhung(0)  # an audio server that died at the end does not hang the exit, nor change its code
    return 0


def cmd_check(a: argparse.Namespace) -> int:
    rig = Rig.load(a.rig)
    report = analyse(capture(rig, a.device, tx=a.tx, rx=a.rx, rest_s=a.rest, press_s=a.press, blocksize=a.blocksize,
                             scenario=a.scenario, fault=a.sim_fault, motors=a.sim_motors), rig)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    print(report.table())
    (out / "check.json").write_text(report.to_json() + "\n")
    report.plot(out / "check.png")
    print(f"wrote {out / 'check.png'} and {out / 'check.json'}", file=sys.stderr)
    return 0 if report.ok else 1


def cmd_record(a: argparse.Namespace) -> int:
    if a.links:
        return _record_arm(a)
    # The scenario gives the layout of the markers (and, on the simulated device, the link and the person).
    # record_session checks the device before writing and removes a dataset it could not record anything into.
    out = Path(a.out)
    with clean_on_failure(out, writer_mode(a)):
        record_session(out, Rig.load(a.rig or "jaco"), Scenario.load(a.scenario), locations=a.locations, device=a.device,
                       resume=a.resume, overwrite=a.overwrite, realtime=not a.fast, calibration_s=a.calibration_s,
                       moving_s=a.moving_s, touch_s=a.touch_s, gap_s=a.gap_s, force_csv=a.force_csv,
                       force_serial=a.force_serial, tx=a.tx, rx=a.rx, passes=a.passes,
                       artifact=None if a.no_artifact else Path(a.artifact or f"{out}-artifact"))
    return 0


def _record_arm(a: argparse.Namespace) -> int:
    """``record --links ARM --out DIR``: every link's guided session in turn into ``DIR/<link>``, each with its artifact."""
    if a.tx or a.rx or a.scenario != "stationary" or a.locations or a.artifact:
        raise UsageError("record --links takes each link's channels and markers from the arm file and writes each link's "
                         "artifact next to its recording (OUT/<link>-artifact); drop --tx, --rx, --scenario, --locations "
                         "and --artifact")
    rig, links = load_arm(a.links, a.rig)
    missing = [lk.name for lk in links if lk.scenario is None]
    if missing:
        raise UsageError(f"--links {a.links}: links {missing} have no `scenario:` to take their markers from; give each "
                         f"link one (its layout is what the prompts ask you to press)")
    root = Path(a.out)
    for lk in links:
        out = root / lk.name
        print(f"link {lk.name} (TX {lk.tx}, RX {lk.rx}): {len(lk.scenario.make_layout())} markers into {out}", file=sys.stderr)
        with clean_on_failure(out, writer_mode(a)):
            record_session(out, lk.rig or rig, lk.scenario, device=a.device, resume=a.resume, overwrite=a.overwrite,
                           realtime=not a.fast, calibration_s=a.calibration_s, moving_s=a.moving_s, touch_s=a.touch_s,
                           gap_s=a.gap_s, force_csv=a.force_csv, force_serial=a.force_serial, tx=lk.tx, rx=lk.rx,
                           passes=a.passes, link=lk,
                           artifact=None if a.no_artifact else Path(f"{out}-artifact"))
    print(f"{len(links)} links recorded under {root}/<link>; train the arm: `sonicskin fit-svm --links {a.links} --data "
          f"{root} --out ART`", file=sys.stderr)
    return 0
