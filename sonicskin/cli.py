"""``sonicskin <verb>``: one command line for the simulated rig, datasets and models."""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import yaml

from . import __version__

EPILOG = """\
typical session on the simulated rig:
  sonicskin simulate --scenario moving --out data/moving      # received audio + labels
  sonicskin evaluate --data data/moving                       # the paper's SVM pipeline + ablations
  sonicskin train --config configs/train/moving.yaml          # the network (Lightning)
  sonicskin export --run runs/moving --out artifacts/moving   # both models -> ONNX + skin.json
  sonicskin compare --data data/moving --artifact artifacts/moving
"""


def _parse_set(items: list[str]) -> dict:
    """``--set key=value`` overrides; values are YAML (``sessions=2``, ``motion={enabled: true}``)."""
    out = {}
    for it in items or []:
        if "=" not in it:
            raise SystemExit(f"--set expects key=value, got {it!r}")
        k, v = it.split("=", 1)
        out[k.strip()] = yaml.safe_load(v)
    return out


def cmd_simulate(a: argparse.Namespace) -> int:
    from .rig import Rig
    from .sim.generate import simulate_dataset
    from .sim.scenario import Scenario

    sc = Scenario.load(a.scenario)
    over = _parse_set(a.set)
    if a.seed is not None:
        over["seed"] = a.seed
    if a.sessions is not None:
        over["sessions"] = a.sessions
    if over:
        sc = Scenario.from_dict({**sc.to_dict(), **over})
    rig = Rig.load(a.rig)
    out = Path(a.out or f"data/{sc.name}")
    mode = "overwrite" if a.overwrite else "resume" if a.resume else "create"
    simulate_dataset(sc, rig, out, mode=mode, progress=not a.quiet)
    print(f"dataset written to {out}")
    return 0


def cmd_evaluate(a: argparse.Namespace) -> int:
    from .dataset import Dataset
    from .evaluate import evaluate_svm, format_report, save_report

    ds = Dataset(a.data)
    res = evaluate_svm(ds, train_sessions=a.train, ablations=not a.no_ablations)
    print(format_report(res))
    out = Path(a.out or Path("reports") / ds.root.name)
    paths = save_report(res, out, ds.layout)
    print("wrote " + ", ".join(str(p) for p in paths))
    return 0


def _need_train_extra(verb: str):
    try:
        import lightning  # noqa: F401
        import torch  # noqa: F401
    except ImportError:
        raise SystemExit(f"sonicskin {verb} needs the training extra: pip install -c constraints.txt 'sonicskin[train]'") from None


def _train_config(name: str) -> str:
    """A training YAML path, or a name under configs/train (works from any directory)."""
    from .rig import _resolve_config

    return str(_resolve_config(name, "train"))


def cmd_train(a: argparse.Namespace, extra: list[str]) -> int:
    _need_train_extra("train")
    from training.cli import main as train_main

    args = ["--config", _train_config(a.config)] + (["--data.data", a.data] if a.data else []) + extra
    cli = train_main(args)
    ckpt = cli.trainer.checkpoint_callback
    print(f"checkpoints: {ckpt.dirpath} (best {ckpt.best_model_path}); config saved beside them")
    return 0


def _latest_checkpoint(run: Path) -> Path:
    if run.is_file():
        return run
    last = sorted(run.rglob("last.ckpt"), key=lambda p: p.stat().st_mtime)
    if not last:
        raise FileNotFoundError(f"no checkpoint under {run}; run `sonicskin train` first")
    d = last[-1].parent
    best = sorted(d.glob("best-*.ckpt"), key=lambda p: p.stat().st_mtime)
    return best[-1] if best else last[-1]


def cmd_export(a: argparse.Namespace) -> int:
    _need_train_extra("export")
    from export.onnx import export_artifact

    ckpt = _latest_checkpoint(Path(a.run))
    export_artifact(ckpt, a.out, data=a.data)
    return 0


def cmd_compare(a: argparse.Namespace, extra: list[str]) -> int:
    from .compare import compare_artifact, format_comparison, save_comparison
    from .rig import Layout

    if a.scenario:  # several simulator and training seeds, paired interval
        _need_train_extra("compare --scenario")
        from .seeds import compare_seeds, format_markdown

        out = Path(a.out or "reports/compare-seeds")
        res = compare_seeds(a.scenario, sim_seeds=a.sim_seeds, train_seeds=a.train_seeds, cache=a.cache, out=out,
                            epochs=a.epochs)
        print(format_markdown(res))
        print(f"wrote {out}/seeds.json, seeds.md, seeds.png")
        return 0
    if not a.data:
        raise SystemExit("sonicskin compare: give --data DATASET (one dataset) or --scenario NAME... (simulated, several seeds)")
    artifact = a.artifact
    if artifact is None:  # train and export both models on the same split first
        _need_train_extra("compare")
        from export.onnx import export_artifact
        from training.cli import main as train_main

        name = Path(a.data).name
        run = Path(a.runs) / f"compare-{name}"
        args = ["--config", _train_config(a.config), "--data.data", a.data, "--trainer.default_root_dir", str(run),
                "--trainer.logger.init_args.save_dir", str(run)]
        if a.test_subjects:
            args += ["--data.test_subjects", json.dumps(a.test_subjects)]
        cli = train_main(args + extra)
        artifact = run / "artifact"
        export_artifact(_latest_checkpoint(Path(cli.trainer.checkpoint_callback.dirpath)), artifact, data=a.data)
    res = compare_artifact(artifact, a.data)
    title = f"{Path(a.data).name}: network vs SVM"
    print(format_comparison(res, title))
    meta = json.loads((Path(artifact) / "skin.json").read_text())
    out = Path(a.out or Path("reports") / f"compare-{Path(a.data).name}")
    paths = save_comparison(res, out, Layout.from_dict(meta["layout"]), title)
    print("wrote " + ", ".join(str(p) for p in paths))
    return 0


def cmd_fit_svm(a: argparse.Namespace) -> int:
    from .artifact import build_svm_artifact

    build_svm_artifact(a.data, a.out, n_bins=a.n_bins, mode=a.mode, train_sessions=a.train)
    return 0


def cmd_devices(a: argparse.Namespace) -> int:
    from .acquire import list_devices

    devs = list_devices()
    if not devs:
        print("no audio devices (PortAudio sees none); `sonicskin live` runs on the simulated device by default")
        return 0
    print(f"{'index':>5}  {'name':40s} {'host API':28s} {'in':>3} {'out':>3}  default rate")
    for d in devs:
        print(f"{d['index']:>5}  {d['name'][:40]:40s} {d['hostapi'][:28]:28s} {d['inputs']:>3} {d['outputs']:>3}  "
              f"{d['default_rate_hz']:g} Hz")
    return 0


def _sim_svm_artifact(scenario, rig, root: Path) -> Path:
    """One-shot training on the simulated link (cached): what `sonicskin record` + `fit-svm` do on a real rig."""
    from .artifact import build_svm_artifact
    from .sim.generate import simulate_dataset

    art = root / f"artifacts/sim-{scenario.name}-svm"
    if (art / "skin.json").is_file():
        return art
    data = root / f"data/sim-{scenario.name}-oneshot"
    print(f"no --artifact: one-shot training on the simulated link first ({data} -> {art})", file=sys.stderr)
    simulate_dataset(scenario.replace(sessions=1), rig, data, mode="overwrite", progress=False,
                     log=lambda m: print(m, file=sys.stderr))
    build_svm_artifact(data, art, progress=False, log=lambda m: print(m, file=sys.stderr))
    return art


def cmd_live(a: argparse.Namespace) -> int:
    from .acquire import Link, SimulatedSource, SoundDeviceSource
    from .live import LiveLoop, UdpSink
    from .rig import Rig
    from .runtime import SkinRuntime

    rig = Rig.load(a.rig)
    if a.device == "sim":
        from .sim import Scenario, Simulator, build_timeline

        sc = Scenario.load(a.scenario)
        artifact = Path(a.artifact) if a.artifact else _sim_svm_artifact(sc, rig, Path("."))
        # The same simulated link (link_seed), a new person-session of scripted touches (seed).
        live_sc = sc.replace(seed=sc.seed + 1000, sessions=1)
        timeline = build_timeline(live_sc, rig)
        source = SimulatedSource(Simulator(live_sc, rig), timeline, realtime=not a.fast, drop_every=a.drop_every)
    else:
        if not a.artifact:
            raise ValueError("a real rig needs a model trained on it: `sonicskin record`, then `sonicskin fit-svm` "
                             "(or train + export), then `sonicskin live --device ... --artifact DIR`")
        artifact = Path(a.artifact)
        source = SoundDeviceSource(rig, a.device, link=Link(tx=a.tx, rx=a.rx), blocksize=a.blocksize)
    rt = SkinRuntime(artifact, a.model, rig=rig)
    sinks = [lambda line: print(line, flush=True)]
    if a.udp:
        sinks.append(UdpSink(a.udp))
    loop = LiveLoop(rt, source, emit=lambda line: [s(line) for s in sinks], status=not a.no_status)
    with source:
        summary = loop.run(duration_s=a.duration)
    print(json.dumps({"summary": summary}), file=sys.stderr)
    return 0


def cmd_record(a: argparse.Namespace) -> int:
    import numpy as np

    from .acquire import Link, SimulatedSource, SoundDeviceSource
    from .dataset import DatasetWriter
    from .record import CsvForce, NoForce, Recorder, SerialForce, TimelineForce, make_schedule, next_session, recorded_locations
    from .rig import Rig
    from .sim import Scenario, Simulator, build_timeline
    from .sim.scenario import SEGMENTS

    rig = Rig.load(a.rig)
    sc = Scenario.load(a.scenario)  # the layout (and, on the simulated device, the link and the person)
    layout = sc.make_layout()
    out = Path(a.out)
    mode = "resume" if a.resume else ("overwrite" if a.overwrite else "create")
    writer = DatasetWriter(out, rig, layout, source={"kind": "recorder", "layout_from": sc.name}, mode=mode)
    todo = list(a.locations) if a.locations else list(layout.ids)
    if a.resume:
        done = recorded_locations(out)
        todo = [loc for loc in todo if loc not in done]
        if not todo:
            print(f"{out}: every location is recorded; nothing to do", file=sys.stderr)
            return 0
    session = next_session(out)
    schedule = make_schedule(layout, todo, rig, calibration_s=a.calibration_s, moving_s=a.moving_s,
                             touch_s=a.touch_s, gap_s=a.gap_s)
    if a.device == "sim":
        # The simulated person follows the prompts: same segments, same order, one extra chirp in front
        # (the stream starts inside a chirp).
        psc = sc.replace(sessions=1, order="sequential", repeats=1, seed=sc.seed + 500 + int(session[1:]),
                         calibration_s=a.calibration_s + rig.period_s, touch_s=a.touch_s, gap_s=a.gap_s,
                         moving_s=a.moving_s, motion={**sc.motion, "enabled": a.moving_s > 0},
                         layout={**sc.layout})
        tl = build_timeline(psc, rig)
        keep = np.isin(tl.location, [-1, *todo]) | (tl.segment != SEGMENTS.index("touch"))
        # Only the prompted locations, in the prompted order; the robot moves only when asked to.
        tl = tl.select(np.isin(tl.event, [-1, *[e for e in np.unique(tl.event) if e >= 0
                                                  and tl.location[tl.event == e][0] in todo]]) & keep)
        tl.moving[tl.segment != SEGMENTS.index("moving")] = 0.0
        src = SimulatedSource(Simulator(psc, rig), tl, realtime=not a.fast, offset=4321)
        force = TimelineForce(tl, -4321, rig.fs_hz, rig.n_chirp, seed=int(session[1:]))
    else:
        src = SoundDeviceSource(rig, a.device, link=Link(tx=a.tx, rx=a.rx))
        force = CsvForce(a.force_csv) if a.force_csv else SerialForce(a.force_serial) if a.force_serial else NoForce()
    print(f"recording session {session} of {out}: {len(todo)} locations, "
          f"{sum(n for _, _, n, _ in schedule) * rig.period_s:.0f} s", file=sys.stderr)
    with src:
        res = Recorder(writer, session, src, schedule, force).run()
    print(f"wrote {res['chirps']} chirps in {res['parts']} parts to {out / session}", file=sys.stderr)
    return 0


def cmd_reproduce(a: argparse.Namespace) -> int:
    from .reproduce import reproduce

    reproduce(a.out, quick=a.quick)
    return 0


def cmd_import_wav(a: argparse.Namespace) -> int:
    from .importers import import_wav

    mode = "overwrite" if a.overwrite else "create"
    import_wav(a.wav_dir, a.labels, a.out, sweep_wav=a.sweep, chirp_hz=tuple(a.chirp) if a.chirp else None,
               period_s=a.period, amplitude=a.amplitude, channel=a.channel, pwm_hz=tuple(a.pwm_hz or ()), pwm_halfwidth_hz=a.pwm_halfwidth,
               mode=mode)
    return 0


def cmd_import_spectra(a: argparse.Namespace) -> int:
    from .importers import import_spectra
    from .rig import Rig

    import_spectra(a.table, a.out, rig=Rig.load(a.rig), mode="overwrite" if a.overwrite else "create")
    return 0


def cmd_info(a: argparse.Namespace) -> int:
    from .rig import CONFIG_DIR, Rig

    rig = Rig.load(a.rig)
    print(f"sonicskin {__version__}")
    print(f"rig {rig.name}: {rig.fs_hz:g} Hz, chirp {rig.f_lo_hz / 1e3:g}-{rig.f_hi_hz / 1e3:g} kHz, "
          f"{rig.n_chirp} samples = {rig.period_s * 1e3:.1f} ms ({rig.chirps_per_s:.3f} chirps/s), "
          f"{rig.n_band} band bins, {int(rig.allowed_mask.sum())} after the PWM notches")
    for kind in ("rigs", "scenarios", "train"):
        names = sorted(p.stem for p in (CONFIG_DIR / kind).glob("*.yaml"))
        if names:
            print(f"{kind}: {', '.join(names)}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="sonicskin", description="SonicSkin: touch localization and force from one "
                                "pair of piezo discs on a robot link. Runs on the simulated rig by default.",
                                epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--version", action="version", version=f"sonicskin {__version__}")
    sub = p.add_subparsers(dest="verb", metavar="<verb>")

    s = sub.add_parser("simulate", help="render a scenario of the simulated rig into a dataset",
                       description="Render a scenario (configs/scenarios/<name>.yaml or a path) into the dataset format.")
    s.add_argument("--scenario", default="stationary", help="scenario name or YAML path (default: stationary)")
    s.add_argument("--rig", default="jaco", help="rig name or YAML path (default: jaco)")
    s.add_argument("--out", help="dataset folder (default: data/<scenario>)")
    s.add_argument("--seed", type=int, help="override the scenario's seed")
    s.add_argument("--sessions", type=int, help="override the number of sessions")
    s.add_argument("--set", action="append", metavar="KEY=VALUE", help="override any scenario key (YAML value)")
    g = s.add_mutually_exclusive_group()
    g.add_argument("--overwrite", action="store_true", help="replace an existing dataset")
    g.add_argument("--resume", action="store_true", help="keep finished sessions of an interrupted run")
    s.add_argument("--quiet", action="store_true", help="no progress bar")
    s.set_defaults(func=cmd_simulate)

    e = sub.add_parser("evaluate", help="train the paper's SVM system on a dataset and report its accuracy",
                       description="Train OSPA + RBF SVM + Alg. 2 + Fourier force on the first session (one-shot), "
                                   "test on the others; print the paper's metrics and ablations; write JSON and PNG.")
    e.add_argument("--data", required=True, help="dataset folder")
    e.add_argument("--train", nargs="+", metavar="SESSION", help="training sessions (default: the first)")
    e.add_argument("--out", help="report folder (default: reports/<dataset name>)")
    e.add_argument("--no-ablations", action="store_true", help="skip the no-OSPA / no-calibration / total-energy runs")
    e.set_defaults(func=cmd_evaluate)

    t = sub.add_parser("train", help="train the network (Lightning; any --trainer.* / --model.* / --data.* override)",
                       description="Train SkinNet jointly for location and force with LightningCLI. Unknown options "
                                   "go to LightningCLI, e.g. --trainer.max_epochs 5 --trainer.devices 2 --trainer.strategy ddp.")
    t.add_argument("--config", default="moving", help="training YAML or a name in configs/train (default: moving)")
    t.add_argument("--data", help="dataset folder (overrides data.data)")
    t.set_defaults(func=cmd_train, passthrough=True)

    x = sub.add_parser("export", help="export the network and the SVM baseline into one ONNX artifact")
    x.add_argument("--run", required=True, help="a checkpoint, or a run folder (its newest best/last checkpoint)")
    x.add_argument("--out", required=True, help="artifact folder to write")
    x.add_argument("--data", help="dataset (default: the one the checkpoint was trained on)")
    x.set_defaults(func=cmd_export)

    c = sub.add_parser("compare", help="network vs SVM on the same splits: table, JSON and PNG",
                       description="Train + export both models (or load --artifact) and compare them on the test "
                                   "sessions: accuracy, < 2 / < 3 cm, Table I force, detection, ONNX latency, size.")
    c.add_argument("--data", help="dataset folder")
    c.add_argument("--artifact", help="use this artifact instead of training")
    c.add_argument("--scenario", nargs="+", metavar="NAME",
                   help="instead of --data: simulate these scenarios with every --sim-seeds, train with every --train-seeds, "
                        "and report mean, std and the paired net - SVM 95 %% interval (e.g. moving stationary)")
    c.add_argument("--sim-seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4], help="simulator seeds (default: 0-4)")
    c.add_argument("--train-seeds", type=int, nargs="+", default=[0, 1], help="network training seeds (default: 0 1)")
    c.add_argument("--epochs", type=int, help="network epochs with --scenario (default: training.quick's)")
    c.add_argument("--cache", default="data/seeds", help="simulated datasets for --scenario (default: data/seeds)")
    c.add_argument("--config", default="moving", help="training YAML or a name in configs/train (default: moving)")
    c.add_argument("--test-subjects", type=int, nargs="+", help="leave-subjects-out: these people are the test set")
    c.add_argument("--runs", default="runs", help="where training runs go (default: runs)")
    c.add_argument("--out", help="report folder (default: reports/compare-<dataset>; reports/compare-seeds with --scenario)")
    c.set_defaults(func=cmd_compare, passthrough=True)

    f = sub.add_parser("fit-svm", help="SVM-only artifact from a recording, no torch needed",
                       description="The paper's system as a deployment artifact (svm.onnx + skin.json), trained on "
                                   "every session of a dataset (or --train) on a machine without torch.")
    f.add_argument("--data", required=True, help="dataset folder")
    f.add_argument("--out", required=True, help="artifact folder to write")
    f.add_argument("--train", nargs="+", metavar="SESSION", help="training sessions (default: all)")
    f.add_argument("--n-bins", type=int, default=300, help="OSPA gamma (default 300)")
    f.add_argument("--mode", choices=("relative", "absolute"), default="relative", help="model inputs (default relative)")
    f.set_defaults(func=cmd_fit_svm)

    lv = sub.add_parser("live", help="real-time touch sensing: audio -> touch events (JSON lines)",
                        description="Run the live loop. By default on the simulated device with scripted touches; "
                                    "--device NAME|INDEX uses a real audio interface (see `sonicskin devices`).")
    lv.add_argument("--device", default="sim", help="'sim' (default) or an audio device name/index")
    lv.add_argument("--artifact", help="artifact folder (sonicskin export / fit-svm); on the simulated device one is "
                                       "trained on the spot when omitted")
    lv.add_argument("--model", choices=("svm", "net"), default="svm", help="which model of the artifact (default svm)")
    lv.add_argument("--scenario", default="stationary", help="simulated device: scenario of the link and the touches")
    lv.add_argument("--rig", default="jaco")
    lv.add_argument("--duration", type=float, default=30.0, help="seconds of stream to run (default 30)")
    lv.add_argument("--udp", metavar="[HOST:]PORT", help="also send events as UDP datagrams (host defaults to 127.0.0.1)")
    lv.add_argument("--tx", type=int, default=0, help="transmit channel (0-based)")
    lv.add_argument("--rx", type=int, default=0, help="receive channel (0-based)")
    lv.add_argument("--blocksize", type=int, default=1024)
    lv.add_argument("--fast", action="store_true", help="simulated device: run faster than real time")
    lv.add_argument("--drop-every", type=int, help="simulated device: drop one audio block in N (fault injection)")
    lv.add_argument("--no-status", action="store_true", help="no status line on stderr")
    lv.set_defaults(func=cmd_live)

    rc = sub.add_parser("record", help="guided one-shot training session -> dataset (resumable)",
                        description="Prompt through hands-off, robot-moving and one touch per location, and write the "
                                    "dataset format as it goes. Ctrl-C keeps every finished prompt; --resume records the "
                                    "locations still missing.")
    rc.add_argument("--out", required=True, help="dataset folder")
    rc.add_argument("--device", default="sim", help="'sim' (default: a simulated person follows the prompts) or an audio device")
    rc.add_argument("--scenario", default="stationary", help="layout of the markers (and the simulated link/person)")
    rc.add_argument("--rig", default="jaco")
    rc.add_argument("--locations", type=int, nargs="+", help="only these location ids (default: all)")
    rc.add_argument("--calibration-s", type=float, default=3.0)
    rc.add_argument("--moving-s", type=float, default=10.0, help="robot moving, hands off (0 skips)")
    rc.add_argument("--touch-s", type=float, default=3.0)
    rc.add_argument("--gap-s", type=float, default=1.0)
    rc.add_argument("--force-csv", help="force log with columns t_s,force_n (real device)")
    rc.add_argument("--force-serial", help="serial port of a force sensor printing newtons per line (real device)")
    rc.add_argument("--tx", type=int, default=0)
    rc.add_argument("--rx", type=int, default=0)
    g2 = rc.add_mutually_exclusive_group()
    g2.add_argument("--resume", action="store_true", help="add a session with the locations not recorded yet")
    g2.add_argument("--overwrite", action="store_true")
    rc.add_argument("--fast", action="store_true", help="simulated device: faster than real time")
    rc.set_defaults(func=cmd_record)

    rp = sub.add_parser("reproduce", help="the paper's Sec. V on the simulated rig, SVM and network side by side",
                        description="Simulate every dataset the paper's experiments need (cached under OUT/data), train "
                                    "both models, write PNG figures and report.md with the paper's numbers beside ours.")
    rp.add_argument("--out", default="reports/reproduce", help="report folder (default reports/reproduce)")
    rp.add_argument("--quick", action="store_true", help="small datasets and short training: a few minutes on 2 cores")
    rp.set_defaults(func=cmd_reproduce)

    iw = sub.add_parser("import-wav", help="import WAV recordings of any sweep and rate (labels in CSV)",
                        description="One WAV/FLAC per continuous recording; labels CSV: file,start_s,end_s,location,"
                                    "x_cm,y_cm[,force_n,moving,subject]. The sweep as a WAV of one period, or --chirp/--period.")
    iw.add_argument("--wav-dir", required=True)
    iw.add_argument("--labels", required=True)
    iw.add_argument("--out", required=True)
    iw.add_argument("--sweep", help="WAV of one period of the transmitted sweep")
    iw.add_argument("--chirp", type=float, nargs=2, metavar=("F_LO_HZ", "F_HI_HZ"), help="linear chirp band")
    iw.add_argument("--period", type=float, help="linear chirp period in seconds")
    iw.add_argument("--amplitude", type=float, default=1.0, help="linear chirp peak amplitude (full scale 1)")
    iw.add_argument("--channel", type=int, default=0, help="receiver channel in the files (0-based)")
    iw.add_argument("--pwm-hz", type=float, nargs="*", help="motor PWM lines to notch (Hz)")
    iw.add_argument("--pwm-halfwidth", type=float, default=0.0)
    iw.add_argument("--overwrite", action="store_true")
    iw.set_defaults(func=cmd_import_wav)

    isp = sub.add_parser("import-spectra", help="import a table of magnitude spectra with labels (.npz)",
                         description="Arrays freqs_hz (F,), magnitude_db (n, F), location, x_cm, y_cm, session "
                                     "[, force_n, moving, subject]; each row becomes one chirp of --rig.")
    isp.add_argument("--table", required=True)
    isp.add_argument("--out", required=True)
    isp.add_argument("--rig", default="jaco")
    isp.add_argument("--overwrite", action="store_true")
    isp.set_defaults(func=cmd_import_spectra)

    dv = sub.add_parser("devices", help="list audio devices")
    dv.set_defaults(func=cmd_devices)

    i = sub.add_parser("info", help="show the rig and the available configs")
    i.add_argument("--rig", default="jaco")
    i.set_defaults(func=cmd_info)
    return p


def main(argv: list[str] | None = None) -> int:
    p = build_parser()
    a, extra = p.parse_known_args(argv)
    if not getattr(a, "func", None):
        p.print_help()
        return 2
    if extra and not getattr(a, "passthrough", False):
        p.error(f"unrecognized arguments: {' '.join(extra)}")
    try:
        return a.func(a, extra) if getattr(a, "passthrough", False) else a.func(a)
    except BrokenPipeError:  # `sonicskin live | head`: the reader went away
        sys.stdout = None
        return 0
    except KeyboardInterrupt:
        print(f"\nsonicskin {a.verb}: interrupted; everything written so far is kept", file=sys.stderr)
        return 130
    except (ValueError, FileNotFoundError, FileExistsError, RuntimeError, OSError) as exc:  # user errors: one line
        print(f"sonicskin {a.verb}: error: {exc}", file=sys.stderr)
        return 2

if __name__ == "__main__":
    raise SystemExit(main())
