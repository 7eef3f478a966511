"""Verbs that write datasets: ``simulate``, ``record``, ``import-wav``, ``import-spectra``.

Every writer takes ``--overwrite`` / ``--resume`` and leaves nothing behind when it fails before
writing a part (:func:`._common.clean_on_failure`; the importers stage their whole output in a
hidden folder and move it into place when complete)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from ..errors import UsageError
from ._common import (
    add_writer_options,
    check_overrides,
    clean_on_failure,
    key_value,
    nonneg_float,
    nonneg_int,
    positive_float,
    positive_int,
    writer_mode,
)


def cmd_simulate(a: argparse.Namespace) -> int:
    from ..rig import Rig
    from ..sim.generate import simulate_dataset
    from ..sim.scenario import Scenario

    if a.links:
        return _simulate_arm(a)
    sc = Scenario.load(a.scenario, seed=a.seed)  # a scenario family (random) draws the rig of that seed
    over = check_overrides(Scenario, a.set, "scenario")
    if a.sessions is not None:
        over["sessions"] = a.sessions
    if over:
        sc = Scenario.from_dict({**sc.to_dict(), **over})
    rig = Rig.load(a.rig or "jaco")
    out = Path(a.out or f"data/{sc.name}")
    mode = writer_mode(a)
    with clean_on_failure(out, mode):
        simulate_dataset(sc, rig, out, mode=mode, progress=not a.quiet)
    print(f"dataset written to {out}")
    return 0


def _simulate_arm(a: argparse.Namespace) -> int:
    """``simulate --links ARM``: one dataset per simulated link of an arm file, ``OUT/<link>``."""
    from ..links import load_arm
    from ..sim.generate import simulate_dataset
    from ..sim.scenario import Scenario

    if a.seed is not None or a.set or a.scenario != "stationary":
        raise UsageError("simulate --links takes each link's scenario from the arm file; --scenario, --seed and --set "
                         "are for one link (edit the arm file's `scenario:` of a link instead)")
    rig, links = load_arm(a.links, a.rig)
    missing = [lk.name for lk in links if lk.scenario is None]
    if missing:
        raise UsageError(f"--links {a.links}: links {missing} have no simulated scenario; give each link a `scenario:`")
    root = Path(a.out or f"data/{Path(str(a.links)).stem}")
    mode = writer_mode(a)
    for lk in links:
        sc = lk.scenario if a.sessions is None else Scenario.from_dict({**lk.scenario.to_dict(), "sessions": a.sessions})
        out = root / lk.name
        print(f"link {lk.name}: scenario {sc.name} ({sc.material}, {sc.geometry['kind']}, {len(sc.make_layout())} markers)",
              file=sys.stderr)
        with clean_on_failure(out, mode):
            simulate_dataset(sc, lk.rig or rig, out, mode=mode, progress=not a.quiet)
    print(f"{len(links)} link datasets written to {root}/<link> ({', '.join(lk.name for lk in links)})")
    return 0


def cmd_record(a: argparse.Namespace) -> int:
    from ..record import record_session
    from ..rig import Rig
    from ..sim import Scenario

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
    """``record --links ARM --out DIR``: the guided session of every link in turn, each on its own TX/RX pair and with
    its own markers (its scenario's layout), into ``DIR/<link>``, each with its artifact (``DIR/<link>-artifact``)
    unless --no-artifact; ``fit-svm --links ARM --data DIR`` trains them all again at once."""
    from ..links import load_arm
    from ..record import record_session

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
                           passes=a.passes,
                           artifact=None if a.no_artifact else Path(f"{out}-artifact"))
    print(f"{len(links)} links recorded under {root}/<link>; train the arm: `sonicskin fit-svm --links {a.links} --data "
          f"{root} --out ART`", file=sys.stderr)
    return 0


def cmd_import_wav(a: argparse.Namespace) -> int:
    from ..importers import import_wav

    # The importer writes into a hidden folder and moves it into place only when complete.
    import_wav(a.wav_dir, a.labels, a.out, sweep_wav=a.sweep, chirp_hz=tuple(a.chirp) if a.chirp else None,
               period_s=a.period, amplitude=a.amplitude, channel=a.channel, pwm_hz=tuple(a.pwm_hz or ()),
               pwm_halfwidth_hz=a.pwm_halfwidth, mode=writer_mode(a))
    return 0


def cmd_import_spectra(a: argparse.Namespace) -> int:
    from ..importers import import_spectra
    from ..rig import Rig

    import_spectra(a.table, a.out, rig=Rig.load(a.rig) if a.rig else None, fs_hz=a.fs, frame=a.frame, linear=a.linear,
                   mode=writer_mode(a))
    return 0


def add_parsers(sub) -> None:
    s = sub.add_parser("simulate", help="render a scenario of the simulated rig into a dataset",
                       description="Render a scenario (configs/scenarios/<name>.yaml or a path) into the dataset format.")
    s.add_argument("--scenario", default="stationary", help="scenario name or YAML path (default: stationary)")
    s.add_argument("--rig", help="rig name or YAML path (default: the --links arm file's rig, else jaco)")
    s.add_argument("--out", help="dataset folder (default: data/<scenario>; --links: data/<arm>, one folder per link)")
    s.add_argument("--links", metavar="ARM",
                   help="simulate every link of an arm file (e.g. arm6; `sonicskin info` lists them) into OUT/<link> "
                        "(default: one link, --scenario)")
    s.add_argument("--seed", type=nonneg_int,
                   help="override the scenario's seed; a family (random) draws another rig per seed (default: the scenario's)")
    s.add_argument("--sessions", type=positive_int, help="override the number of sessions (default: the scenario's)")
    s.add_argument("--set", action="append", type=key_value, metavar="KEY=VALUE",
                   help="override any scenario key, value in YAML (e.g. motion={enabled: true}; default: none)")
    add_writer_options(s)
    s.add_argument("--quiet", action="store_true", help="no progress bar (default: a bar on a terminal)")
    s.set_defaults(func=cmd_simulate)

    rc = sub.add_parser("record", help="guided one-shot training session -> dataset (resumable)",
                        description="Prompt through hands-off, robot-moving and one touch per location, and write the "
                                    "dataset format as it goes. Ctrl-C keeps every finished prompt; --resume records the "
                                    "locations still missing.")
    rc.add_argument("--out", required=True, help="dataset folder")
    rc.add_argument("--device", default="sim",
                    help="'sim' (a simulated person follows the prompts) or an audio device name/index (default: sim)")
    rc.add_argument("--scenario", default="stationary",
                    help="layout of the markers (and the simulated link/person) (default: stationary)")
    rc.add_argument("--rig", help="rig name or YAML path (default: the --links arm file's rig, else jaco)")
    rc.add_argument("--links", metavar="ARM", help="record every link of an arm file in turn, each on its TX/RX pair "
                                                   "with its markers, into OUT/<link> (default: one link)")
    rc.add_argument("--locations", type=nonneg_int, nargs="+", metavar="ID", help="only these location ids (default: all)")
    rc.add_argument("--calibration-s", type=positive_float, default=3.0, help="hands-off calibration, seconds (default: 3)")
    rc.add_argument("--moving-s", type=nonneg_float, default=10.0, help="robot moving, hands off, seconds; 0 skips (default: 10)")
    rc.add_argument("--touch-s", type=positive_float, default=3.0, help="press per location, seconds (default: 3)")
    rc.add_argument("--gap-s", type=nonneg_float, default=1.0, help="pause between presses, seconds (default: 1)")
    rc.add_argument("--passes", type=positive_int, default=3,
                    help="passes over the markers (one press per location each): validation of the model's choices and the "
                         "learning curve need two, the third adds presses of every marker to learn from (default: 3)")
    rc.add_argument("--artifact", help="when every marker is pressed, write the deployable SVM artifact here, as fit-svm "
                                       "would (default: OUT-artifact beside the dataset)")
    rc.add_argument("--no-artifact", action="store_true",
                    help="record only; train later with fit-svm or compare (default: write the artifact)")
    rc.add_argument("--force-csv", help="force log with columns t_s,force_n (real device; default: no force sensor)")
    rc.add_argument("--force-serial", help="serial port of a force sensor printing newtons per line (real device; default: none)")
    rc.add_argument("--tx", type=nonneg_int, default=0, help="transmit channel, 0-based (default: 0)")
    rc.add_argument("--rx", type=nonneg_int, default=0, help="receive channel, 0-based (default: 0)")
    add_writer_options(rc)
    rc.add_argument("--fast", action="store_true", help="simulated device: faster than real time (default: real time)")
    rc.set_defaults(func=cmd_record)

    iw = sub.add_parser("import-wav", help="import WAV recordings of any sweep and rate (labels in CSV)",
                        description="One WAV/FLAC per continuous recording (= one session); labels CSV: file,start_s,end_s,"
                                    "location[,x_cm,y_cm,force_n,moving,subject]. Locations may be ids, numbers (e.g. cm) "
                                    "or names; the label -> id mapping is printed. The sweep as a WAV of one period, or "
                                    "--chirp/--period for a linear chirp.")
    iw.add_argument("--wav-dir", required=True, help="folder of .wav/.flac recordings")
    iw.add_argument("--labels", required=True, help="CSV of touch intervals (see above)")
    iw.add_argument("--out", required=True, help="dataset folder to write")
    iw.add_argument("--sweep", help="WAV of one period of the transmitted sweep, any sweep, at the recordings' rate "
                                    "(default: --chirp/--period)")
    iw.add_argument("--chirp", type=positive_float, nargs=2, metavar=("F_LO_HZ", "F_HI_HZ"),
                    help="linear chirp band, Hz, with --period (default: --sweep)")
    iw.add_argument("--period", type=positive_float, help="linear chirp period in seconds, with --chirp (default: --sweep)")
    iw.add_argument("--amplitude", type=positive_float, default=1.0, help="linear chirp peak amplitude, full scale 1 (default: 1)")
    iw.add_argument("--channel", type=nonneg_int, default=0, help="receiver channel in the files, 0-based (default: 0)")
    iw.add_argument("--pwm-hz", type=positive_float, nargs="*", help="motor PWM lines to notch, Hz (default: none)")
    iw.add_argument("--pwm-halfwidth", type=nonneg_float, default=0.0, help="half width of each PWM notch, Hz (default: 0)")
    add_writer_options(iw)
    iw.set_defaults(func=cmd_import_wav)

    isp = sub.add_parser("import-spectra", help="import a table of magnitude spectra with labels (.npz)",
                         description="Arrays freqs_hz (F,), magnitude_db (n, F), location, session [, x_cm, y_cm, "
                                     "force_n, moving, subject]. The rig is derived from the frequency axis (bin spacing "
                                     "= fs / frame); levels are normalised (no dB offset to choose). Locations may be ids, "
                                     "numbers (e.g. cm) or names; the label -> id mapping is printed.")
    isp.add_argument("--table", required=True, help=".npz table of spectra")
    isp.add_argument("--out", required=True, help="dataset folder to write")
    isp.add_argument("--fs", type=positive_float, help="sample rate of the recordings in Hz (default: from the axis)")
    isp.add_argument("--frame", type=positive_int, help="samples per FFT frame (default: sample rate / bin spacing)")
    isp.add_argument("--linear", action="store_true", help="magnitude_db holds linear magnitudes |H|, not dB (default: dB)")
    isp.add_argument("--rig", help="use this rig (name or YAML) instead of deriving one from the axis (default: derived)")
    add_writer_options(isp)
    isp.set_defaults(func=cmd_import_spectra)
