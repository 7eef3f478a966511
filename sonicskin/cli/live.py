"""Verbs around the running skin: ``live``, ``devices``, ``info``."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from .. import __version__
from ..errors import UsageError
from ..jsonio import json_safe
from ..lsl import LslSink
from ..rig import CONFIG_DIR, Rig
from ._common import nonneg_int, positive_float, positive_int, udp_target


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
    """One link (``--artifact``) or several on one interface (``--links``, a links or arm file: one model and one loop
    per link), on the simulated device or an interface (:func:`sonicskin.session.open_run`); without an artifact a
    simulated link is trained on the spot, once."""
    # here, not at the top: `sonicskin simulate` and every verb but live load neither onnxruntime nor scikit-learn
    from ..acquire import DeviceLost, check_blocksize
    from ..live import UdpSink
    from ..record import train_oneshot
    from ..session import open_run, simulated

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
                   train=train_oneshot, mcap=a.mcap, overwrite=a.overwrite)
    loops = run.loops(emit=lambda line: [s(line) for s in sinks], status=not a.no_status, view=a.view)
    if run.view is not None:
        print(f"sonicskin live: the live view is at {run.view.url} (open it in a browser on this machine)",
              file=sys.stderr, flush=True)
    lost = None
    try:
        summary = run.run(duration_s=a.duration, watchdog_s=a.watchdog)
    except DeviceLost as e:
        lost, summary = e, run.summary([lp.summary(0.0, 0.0, 0.0) for lp in loops])
    out = {"summary": json_safe(summary)}
    if run.mcap is not None:
        out["mcap"] = {"path": str(a.mcap), "events": run.mcap.written, "messages": run.mcap.messages}
    print(json.dumps(out, allow_nan=False), file=sys.stderr)
    if lost is not None:
        raise lost
    return 0


def cmd_check(a: argparse.Namespace) -> int:
    from ..check import analyse, capture

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


def cmd_devices(a: argparse.Namespace) -> int:
    from ..acquire import list_devices

    devs = list_devices()
    if not devs:
        print("no audio devices (PortAudio sees none); `sonicskin live` runs on the simulated device by default")
        return 0
    print(f"{'index':>5}  {'name':40s} {'host API':28s} {'in':>3} {'out':>3}  default rate")
    for d in devs:
        print(f"{d['index']:>5}  {d['name'][:40]:40s} {d['hostapi'][:28]:28s} {d['inputs']:>3} {d['outputs']:>3}  "
              f"{d['default_rate_hz']:g} Hz")
    return 0


def cmd_info(a: argparse.Namespace) -> int:
    rig = Rig.load(a.rig)
    print(f"sonicskin {__version__}")
    print(f"rig {rig.name}: {rig.fs_hz:g} Hz, chirp {rig.f_lo_hz / 1e3:g}-{rig.f_hi_hz / 1e3:g} kHz, "
          f"{rig.n_chirp} samples = {rig.period_s * 1e3:.1f} ms ({rig.chirps_per_s:.3f} chirps/s), "
          f"{rig.n_band} band bins, {int(rig.allowed_mask.sum())} after the PWM notches")
    for kind in ("rigs", "scenarios", "train", "links", "arms"):
        names = sorted(p.stem for p in (CONFIG_DIR / kind).glob("*.yaml"))
        if names:
            print(f"{kind}: {', '.join(names)}")
    return 0


def _device_options(p: argparse.ArgumentParser) -> None:
    """The device and its channels, as ``live`` and ``check`` take them."""
    p.add_argument("--device", default="sim", help="'sim' or an audio device name/index (default: sim)")
    p.add_argument("--tx", type=nonneg_int, default=0, help="transmit channel, 0-based (default: 0)")
    p.add_argument("--rx", type=nonneg_int, default=0, help="receive channel, 0-based (default: 0)")
    p.add_argument("--blocksize", type=positive_int, default=1024, help="audio block in samples, at most 1048576 "
                   "(default: 1024)")


def add_parsers(sub) -> None:
    lv = sub.add_parser("live", help="real-time touch sensing: audio -> touch events (JSON lines)",
                        description="Run the live loop. By default on the simulated device with scripted touches; "
                                    "--device NAME|INDEX uses a real audio interface (see `sonicskin devices`). "
                                    "Touch events go to stdout as JSON lines, a summary to stderr at the end. "
                                    "Without --artifact on the simulated device, an SVM is trained first, once: it "
                                    "takes about 2 min (the stationary scenario, an idle 2-core machine), writes about "
                                    "200 MB of simulated recordings to ./data/sim-SCENARIO-oneshot and the artifact to "
                                    "./artifacts/sim-SCENARIO-svm, which later runs reuse; a line on stderr says so "
                                    "before it starts. The run stops with one line when the device stops delivering "
                                    "(--watchdog), or when its input holds no usable chirp (silent, NaN, clipped, "
                                    "constant, or noise without the chirp).")
    lv.set_defaults(func=cmd_live)
    _device_options(lv)
    lv.add_argument("--artifact", help="artifact folder (sonicskin export / fit-svm) (default: on the simulated device, "
                                       "an SVM is trained on the spot the first time, about 2 min and 200 MB under ./data "
                                       "and ./artifacts, and reused later)")
    lv.add_argument("--model", metavar="KIND", help="which model of the artifact: svm (the paper's), lda (the closed-form "
                                                  "LDA) or net (the network) (default: svm)")
    lv.add_argument("--scenario", default="stationary",
                    help="simulated device: scenario of the link and the touches (default: stationary)")
    lv.add_argument("--rig", help="rig name or YAML path (default: the --artifact's own rig, else jaco)")
    lv.add_argument("--duration", type=positive_float, default=30.0,
                    help="seconds to run, by the clock (--fast: seconds of simulated stream) (default: 30)")
    lv.add_argument("--udp", type=udp_target, metavar="[HOST:]PORT",
                    help="also send events as UDP datagrams; host defaults to 127.0.0.1 (default: off)")
    lv.add_argument("--lsl", metavar="NAME", nargs="?", const="sonicskin",
                    help="also publish events as a Lab Streaming Layer string stream of this name (needs pylsl: "
                         "pip install 'sonicskin[lsl]') (default: off; NAME defaults to sonicskin)")
    lv.add_argument("--watchdog", type=positive_float, default=3.0, metavar="S",
                    help="stop with an error when the device (or the simulated one, --fast too) delivers no audio, or no "
                         "usable chirp, for S seconds (default: 3)")
    lv.add_argument("--fast", action="store_true", help="simulated device: run faster than real time (default: real time)")
    lv.add_argument("--drop-every", type=positive_int, metavar="N",
                    help="simulated device: drop one audio block in N (N >= 2), fault injection (default: none)")
    lv.add_argument("--no-status", action="store_true", help="no status line on stderr (default: one a second)")
    lv.add_argument("--links", metavar="NAME",
                    help="several links on one interface: a links config with --device and one --link-artifact per link "
                         "(e.g. two-links-time), or an arm file (e.g. arm6, or the ART/arm.yaml that `fit-svm --links` "
                         "writes): its links simulated on the default device, events in each link's frame (`sonicskin "
                         "info` lists them) (default: one link, --tx/--rx)")
    lv.add_argument("--view", metavar="PORT", nargs="?", const="0",
                    help="show the skin live in a browser at http://127.0.0.1:PORT/ (every link unrolled to scale, the "
                         "touch and its force, the last events, the reference and drift state); PORT omitted: any free "
                         "port, printed on stderr (default: off)")
    lv.add_argument("--mcap", metavar="FILE",
                    help="with --links on an arm: also write every touch as ROS 2 messages (contact point and wrench in "
                         "the link's frame, markers) into the MCAP file FILE, for `ros2 bag play` and Foxglove "
                         "(docs/robot-frame.md) (default: off)")
    lv.add_argument("--overwrite", action="store_true", help="replace an existing --mcap file (default: refuse it)")
    lv.add_argument("--link-artifact", action="append", metavar="DIR",
                    help="with --links: the artifact of each link, once per link in the config's order (default: none)")
    ck = sub.add_parser("check", help="rig check: chirp, delay, level, SNR, PWM lines, repeatability, touch contrast",
                        description="Play the rig's chirp, record every input, ask for one firm press, and print one table: "
                                    "each measurement with pass/warn/fail and its fix. Writes check.png (|H(f)| at rest and "
                                    "pressed, noise floor, PWM bands, the band used) and check.json to --out. Exit code 0 "
                                    "when nothing fails, 1 otherwise. Runs on the simulated device by default.")
    ck.set_defaults(func=cmd_check)
    _device_options(ck)
    ck.add_argument("--rig", default="jaco", help="rig name or YAML path (default: jaco)")
    ck.add_argument("--rest", type=positive_float, default=4.0, help="seconds of hands-off chirps (default: 4)")
    ck.add_argument("--press", type=positive_float, default=3.0,
                    help="seconds of the press, at least 3 chirp periods (0.4 s on jaco) (default: 3)")
    ck.add_argument("--out", default=".", help="folder for check.png and check.json (default: .)")
    ck.add_argument("--scenario", default="stationary", help="simulated device: the link (default: stationary)")
    ck.add_argument("--sim-fault", default="none", choices=("none", "disconnected", "clipping", "weak", "wrong-channel", "rate"),
                    help="simulated device: inject a fault (default: none)")
    ck.add_argument("--sim-motors", type=float, default=0.0, metavar="LEVEL",
                    help="simulated device: motor activity 0..1 during the check (default: 0, robot still)")
    dv = sub.add_parser("devices", help="list audio devices",
                        description="List the audio interfaces PortAudio sees (index, name, host API, input and output "
                                    "channels, default rate), for `sonicskin live/record --device NAME|INDEX`. Needs "
                                    "libportaudio2; the simulated device needs none.")
    dv.set_defaults(func=cmd_devices)
    i = sub.add_parser("info", help="show the version, the rig and the available configs",
                       description="Print the package version, the rig's sample rate, chirp, period and usable bins, "
                                   "and the names of the shipped rig, scenario, training and links configs (usable as "
                                   "--rig/--scenario/--config NAME, and `live --links NAME`).")
    i.set_defaults(func=cmd_info)
    i.add_argument("--rig", default="jaco", help="rig name or YAML path (default: jaco)")
