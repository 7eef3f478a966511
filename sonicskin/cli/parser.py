"""The command line's grammar: every verb, its options and their value types.  Each verb names its implementation as
``"module:function"``, imported by :func:`sonicskin.cli.main` only when that verb runs."""

from __future__ import annotations

import argparse
import contextlib
import importlib
import importlib.util
import math
import sys

from .. import __version__, threads
from ..errors import UsageError
from ..features import DEFAULT_N_BINS, FeatureSpec

# sonicskin.reproduce.EXPERIMENTS, spelled out so that building the parser does not import the simulator (4 s)
REPRODUCE_EXPERIMENTS = ("fig6b", "fig11", "fig12", "fig13", "table1", "fig16")

EPILOG = """\
typical session on the simulated rig:
  sonicskin simulate --scenario moving --out data/moving      # received audio + labels
  sonicskin evaluate --data data/moving                       # the paper's SVM pipeline + ablations
  sonicskin train --config moving --data data/moving          # the network (Lightning)
  sonicskin export --run runs/moving --out artifacts/moving   # both models -> ONNX + skin.json
  sonicskin compare --data data/moving --artifact artifacts/moving

every verb: sonicskin <verb> --help
"""


# -- value types (argparse ``type=``): a bad value is a usage error naming the option ----------------
def _number(kind, text: str, what: str):
    try:
        v = kind(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
    if kind is float and not math.isfinite(v):
        raise argparse.ArgumentTypeError(f"expected a finite number, got {text!r}")
    return v


def _bounded(kind, what: str, positive: bool):
    """An argparse type: a ``kind`` (float or int) that is > 0 (``positive``) or >= 0."""
    rule = "> 0" if positive else ">= 0"

    def parse(text: str):
        v = _number(kind, text, f"{what} {rule}")
        if v < 0 or (positive and v == 0):
            raise argparse.ArgumentTypeError(f"must be {rule}, got {text}")
        return v

    parse.__name__ = f"{'positive' if positive else 'nonneg'}_{kind.__name__}"
    return parse


positive_float = _bounded(float, "a number", positive=True)
nonneg_float = _bounded(float, "a number", positive=False)
positive_int = _bounded(int, "a whole number", positive=True)
nonneg_int = _bounded(int, "a whole number", positive=False)


def udp_target(text: str) -> tuple[str, int]:
    """``[HOST:]PORT`` with a port in 1-65535 (host defaults to 127.0.0.1)."""
    host, _, port = text.rpartition(":")
    try:
        p = int(port)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected [HOST:]PORT with a port number 1-65535, got {text!r}") from None
    if not 1 <= p <= 65535:
        raise argparse.ArgumentTypeError(f"port must be 1-65535, got {p}")
    return (host or "127.0.0.1"), p


def key_value(text: str) -> tuple[str, object]:
    """``KEY=VALUE`` with VALUE read as YAML (``sessions=2``, ``motion={enabled: true}``)."""
    import yaml

    k, sep, v = text.partition("=")
    if not sep or not k.strip():
        raise argparse.ArgumentTypeError(f"expected KEY=VALUE, got {text!r}")
    try:
        value = yaml.safe_load(v)
    except yaml.YAMLError:
        raise argparse.ArgumentTypeError(f"{k.strip()}: {v!r} is not a YAML value") from None
    if isinstance(value, str) and v.strip()[:1] not in "'\"":  # YAML 1.1 reads 1e-9 (no dot) as text
        with contextlib.suppress(ValueError):
            value = float(value)
    return k.strip(), value


# -- option groups ---------------------------------------------------------------------------------------
def _verb(sub, name: str, func: str, *, help: str, description: str, add_help: bool = True,
          **defaults) -> argparse.ArgumentParser:
    """A verb's parser; ``func`` is its implementation, ``"module:function"`` of this package's CLI."""
    p = sub.add_parser(name, help=help, description=description, add_help=add_help)
    p.set_defaults(func=func, **defaults)
    return p


def add_model_options(p: argparse.ArgumentParser, *, train_default: str = "the first") -> None:
    """The options every model verb shares: OSPA bins, model inputs and the split of sessions / people."""
    g = p.add_argument_group("model and split options (the same on evaluate, fit-svm, train, export, compare)")
    g.add_argument("--n-bins", type=positive_int, metavar="GAMMA",
                   help=f"OSPA gamma, the bins the SVM reads (default: chosen by validation in fit-svm, train, export and "
                        f"compare; the paper's {DEFAULT_N_BINS} in evaluate; never more than the band's usable bins)")
    g.add_argument("--mode", choices=("relative", "absolute"),
                   help="model inputs: minus the no-touch reference (Alg. 2) or absolute (default: relative)")
    g.add_argument("--train", nargs="+", metavar="SESSION", help=f"training sessions (default: {train_default})")
    g.add_argument("--val", nargs="+", metavar="SESSION",
                   help="validation sessions, or 'none' for no validation (default: the second when there are three or more and --test is "
                        "not given, else none)")
    g.add_argument("--test", nargs="+", metavar="SESSION", help="test sessions (default: all the others)")
    g.add_argument("--test-subjects", type=nonneg_int, nargs="+", metavar="ID",
                   help="leave-subjects-out: sessions of these people are the test set (default: off)")
    g.add_argument("--no-refit", dest="refit", action="store_false",
                   help="deploy the models fitted on the training sessions alone (default: after choosing on the validation session, "
                        "refit every model on the training and validation sessions together)")
    g.add_argument("--alpha-s", type=positive_float, metavar="S",
                   help=f"Alg. 2's refresh interval: the no-touch reference of relative inputs is renewed every S seconds "
                        f"(default: {FeatureSpec.alpha_s:g})")
    g.add_argument("--beta-s", type=positive_float, metavar="S",
                   help=f"Alg. 2's reference length: the mean of S seconds of hands-off chirps (default: {FeatureSpec.beta_s:g}, "
                        f"or the longest rest every session holds when that is shorter)")


def add_writer_options(p: argparse.ArgumentParser, what: str = "dataset") -> None:
    """``--overwrite`` / ``--resume``, the same on every verb that writes a dataset."""
    g = p.add_mutually_exclusive_group()
    g.add_argument("--overwrite", action="store_true", help=f"replace an existing {what} (default: refuse)")
    g.add_argument("--resume", action="store_true",
                   help=f"continue an interrupted {what}: keep what is complete, add what is missing (default: off)")


def _device_options(p: argparse.ArgumentParser) -> None:
    """The device and its channels, as ``live`` and ``check`` take them."""
    p.add_argument("--device", default="sim", help="'sim' or an audio device name/index (default: sim)")
    p.add_argument("--tx", type=nonneg_int, default=0, help="transmit channel, 0-based (default: 0)")
    p.add_argument("--rx", type=nonneg_int, default=0, help="receive channel, 0-based (default: 0)")
    p.add_argument("--blocksize", type=positive_int, default=1024, help="audio block in samples, at most 1048576 (default: 1024)")


def _data_verbs(sub) -> None:
    s = _verb(sub, "simulate", "data:cmd_simulate", help="render a scenario of the simulated rig into a dataset",
              description="Render a scenario (configs/scenarios/<name>.yaml or a path) into the dataset format.")
    s.add_argument("--scenario", default="stationary", help="scenario name or YAML path (default: stationary)")
    s.add_argument("--rig", help="rig name or YAML path (default: the --links arm file's rig, else jaco)")
    s.add_argument("--out", help="dataset folder (default: data/<scenario>; --links: data/<arm>, one folder per link)")
    s.add_argument("--links", metavar="ARM",
                   help="simulate every link of an arm file (e.g. arm6; `sonicskin info` lists them) into OUT/<link> (default: one link, "
                        "--scenario)")
    s.add_argument("--seed", type=nonneg_int,
                   help="override the scenario's seed; a family (random) draws another rig per seed (default: the scenario's)")
    s.add_argument("--sessions", type=positive_int, help="override the number of sessions (default: the scenario's)")
    s.add_argument("--set", action="append", type=key_value, metavar="KEY=VALUE",
                   help="override any scenario key, value in YAML (e.g. motion={enabled: true}; default: none)")
    add_writer_options(s)
    s.add_argument("--quiet", action="store_true", help="no progress bar (default: a bar on a terminal)")

    rc = _verb(sub, "record", "live:cmd_record", help="guided one-shot training session -> dataset (resumable)",
               description="Prompt through hands-off, robot-moving and one touch per location, and write the dataset format as it goes. "
                           "Ctrl-C keeps every finished prompt; --resume records the locations still missing.")
    rc.add_argument("--out", required=True, help="dataset folder")
    rc.add_argument("--device", default="sim",
                    help="'sim' (a simulated person follows the prompts) or an audio device name/index (default: sim)")
    rc.add_argument("--scenario", default="stationary", help="layout of the markers (and the simulated link/person) (default: stationary)")
    rc.add_argument("--rig", help="rig name or YAML path (default: the --links arm file's rig, else jaco)")
    rc.add_argument("--links", metavar="ARM", help="record every link of an arm file in turn, each on its TX/RX pair with its markers, "
                                                   "into OUT/<link> (default: one link)")
    rc.add_argument("--locations", type=nonneg_int, nargs="+", metavar="ID", help="only these location ids (default: all)")
    rc.add_argument("--calibration-s", type=positive_float, default=3.0, help="hands-off calibration, seconds (default: 3)")
    rc.add_argument("--moving-s", type=nonneg_float, default=10.0, help="robot moving, hands off, seconds; 0 skips (default: 10)")
    rc.add_argument("--touch-s", type=positive_float, default=3.0, help="press per location, seconds (default: 3)")
    rc.add_argument("--gap-s", type=nonneg_float, default=1.0, help="pause between presses, seconds (default: 1)")
    rc.add_argument("--passes", type=positive_int, default=3,
                    help="passes over the markers (one press per location each): validation of the model's choices and the learning curve "
                         "need two, the third adds presses of every marker to learn from (default: 3)")
    rc.add_argument("--artifact", help="when every marker is pressed, write the deployable SVM artifact here, as fit-svm would (default: "
                                       "OUT-artifact beside the dataset)")
    rc.add_argument("--no-artifact", action="store_true",
                    help="record only; train later with fit-svm or compare (default: write the artifact)")
    rc.add_argument("--force-csv", help="force log with columns t_s,force_n (real device; default: no force sensor)")
    rc.add_argument("--force-serial", help="serial port of a force sensor printing newtons per line (real device; default: none)")
    rc.add_argument("--tx", type=nonneg_int, default=0, help="transmit channel, 0-based (default: 0)")
    rc.add_argument("--rx", type=nonneg_int, default=0, help="receive channel, 0-based (default: 0)")
    add_writer_options(rc)
    rc.add_argument("--fast", action="store_true", help="simulated device: faster than real time (default: real time)")

    iw = _verb(sub, "import-wav", "data:cmd_import_wav", help="import WAV recordings of any sweep and rate (labels in CSV)",
               description="One WAV/FLAC per continuous recording (= one session); labels CSV: "
                           "file,start_s,end_s,location[,x_cm,y_cm,force_n,moving,subject]. Locations may be ids, numbers (e.g. cm) or "
                           "names; the label -> id mapping is printed. The sweep as a WAV of one period, or --chirp/--period for a linear "
                           "chirp.")
    iw.add_argument("--wav-dir", required=True, help="folder of .wav/.flac recordings")
    iw.add_argument("--labels", required=True, help="CSV of touch intervals (see above)")
    iw.add_argument("--out", required=True, help="dataset folder to write")
    iw.add_argument("--sweep", help="WAV of one period of the transmitted sweep, any sweep, at the recordings' rate (default: "
                                    "--chirp/--period)")
    iw.add_argument("--chirp", type=positive_float, nargs=2, metavar=("F_LO_HZ", "F_HI_HZ"),
                    help="linear chirp band, Hz, with --period (default: --sweep)")
    iw.add_argument("--period", type=positive_float, help="linear chirp period in seconds, with --chirp (default: --sweep)")
    iw.add_argument("--amplitude", type=positive_float, default=1.0, help="linear chirp peak amplitude, full scale 1 (default: 1)")
    iw.add_argument("--channel", type=nonneg_int, default=0, help="receiver channel in the files, 0-based (default: 0)")
    iw.add_argument("--pwm-hz", type=positive_float, nargs="*", help="motor PWM lines to notch, Hz (default: none)")
    iw.add_argument("--pwm-halfwidth", type=nonneg_float, default=0.0, help="half width of each PWM notch, Hz (default: 0)")
    add_writer_options(iw)

    isp = _verb(sub, "import-spectra", "data:cmd_import_spectra", help="import a table of magnitude spectra with labels (.npz)",
                description="Arrays freqs_hz (F,), magnitude_db (n, F), location, session [, x_cm, y_cm, force_n, moving, subject]. The "
                            "rig is derived from the frequency axis (bin spacing = fs / frame); levels are normalised (no dB offset to "
                            "choose). Locations may be ids, numbers (e.g. cm) or names; the label -> id mapping is printed.")
    isp.add_argument("--table", required=True, metavar="NPZ", help=".npz table of spectra")
    isp.add_argument("--out", required=True, help="dataset folder to write")
    isp.add_argument("--fs", type=positive_float, help="sample rate of the recordings in Hz (default: from the axis)")
    isp.add_argument("--frame", type=positive_int, help="samples per FFT frame (default: sample rate / bin spacing)")
    isp.add_argument("--linear", action="store_true", help="magnitude_db holds linear magnitudes |H|, not dB (default: dB)")
    isp.add_argument("--rig", help="use this rig (name or YAML) instead of deriving one from the axis (default: derived)")
    add_writer_options(isp)


def _model_verbs(sub) -> None:
    e = _verb(sub, "evaluate", "models:cmd_evaluate", help="train the paper's SVM system on a dataset and report its accuracy",
              description="Train OSPA + RBF SVM + Alg. 2 + Fourier force on the first session (one-shot), test on the others; print the "
                          "paper's metrics and ablations; write JSON and PNG. --mode relative calibrates the scores online (Alg. 2); "
                          "absolute keeps the training session's reference throughout.")
    e.add_argument("--data", required=True, help="dataset folder")
    e.add_argument("--out", help="report folder (default: reports/<dataset name>)")
    e.add_argument("--no-ablations", action="store_true", help="skip the no-OSPA / no-calibration / total-energy runs (default: run them)")
    add_model_options(e)

    f = _verb(sub, "fit-svm", "models:cmd_fit_svm", help="SVM-only artifact from a recording, no torch needed",
              description="The paper's system as a deployment artifact (svm.onnx + skin.json), trained on every session of a dataset (or "
                          "--train) on a machine without torch.")
    f.add_argument("--data", required=True, help="dataset folder (with --links: one dataset per link, DATA/<link>)")
    f.add_argument("--out", required=True, help="artifact folder to write (with --links: OUT/<link> and OUT/arm.yaml)")
    f.add_argument("--links", metavar="ARM", help="an arm file: one artifact per link and the arm file that lists them (default: one "
                                                  "link)")
    add_model_options(f, train_default="all")

    t = _verb(sub, "train", "train:cmd_train", passthrough=True, add_help=False,
              help="train the network (Lightning; any --trainer.* / --model.* / --data.* override)",
              description="Train SkinNet jointly for location and force with LightningCLI. Options not listed here go to LightningCLI, "
                          "e.g. --trainer.max_epochs 5 --model.hidden '[64, 64]' --data.batch_size 64; their full list (model, data, "
                          "trainer) follows below when the training extra is installed.")
    t.add_argument("-h", "--help", action=_LightningHelp)
    t.add_argument("--config", default="moving", help="training YAML or a name in configs/train (default: moving)")
    t.add_argument("--data", help="dataset folder (default: data.data of the config)")
    add_model_options(t)

    x = _verb(sub, "export", "train:cmd_export", help="export the network and the SVM baseline into one ONNX artifact",
              description="Write a deployment artifact from a training run: net.onnx (the network), svm.onnx (the paper's SVM, trained "
                          "here on the run's own split and bins) and skin.json (rig, layout, bins, calibration, force curves, checksums), "
                          "each checked for parity against the original. Bins, inputs and split come from the checkpoint.")
    x.add_argument("--run", required=True, help="a checkpoint (.ckpt), or a run folder (its newest best/last checkpoint)")
    x.add_argument("--out", required=True, help="artifact folder to write")
    x.add_argument("--data", help="dataset (default: the one the checkpoint was trained on)")
    add_model_options(x)

    c = _verb(sub, "compare", "models:cmd_compare", passthrough=True, help="network vs SVM on the same splits: table, JSON and PNG",
              description="Train + export both models (or load --artifact: a network + SVM artifact, or a `fit-svm` one) and compare them "
                          "on the test sessions: accuracy, < 2 / < 3 cm, Table I force, detection, ONNX latency, size. The report names "
                          "the train, validation and test sessions and how many chirps of each location it scored. With --test, exactly "
                          "those sessions are tested (the rest not in --train validate unless --val says otherwise). Without --artifact, "
                          "other options go to LightningCLI as in `sonicskin train`.")
    c.add_argument("--data", help="dataset folder (required unless --scenario; with --links: DATA/<link>) (default: none)")
    c.add_argument("--links", metavar="ARM", help="compare every link of an arm file on DATA/<link> (with --artifact: the trained arm), a "
                                                  "report per link in OUT/<link> (default: one link)")
    c.add_argument("--artifact", help="use this artifact instead of training (default: train both models first)")
    c.add_argument("--scenario", nargs="+", metavar="NAME",
                   help="instead of --data: simulate these scenarios with every --sim-seeds, train with every --train-seeds, and report "
                        "mean, std and the paired net - SVM 95 %% interval (e.g. moving stationary; default: none)")
    c.add_argument("--sim-seeds", type=int, nargs="+", default=[0, 1, 2], help="simulator seeds (default: 0 1 2)")
    c.add_argument("--train-seeds", type=int, nargs="+", default=[0, 1], help="network training seeds (default: 0 1)")
    c.add_argument("--epochs", type=int, help="network epochs with --scenario (default: training.quick's)")
    c.add_argument("--rig", help="with --scenario: the simulated rig, a name (jaco, fast) or a YAML path (default: jaco)")
    c.add_argument("--cache", default="data/seeds", help="simulated datasets for --scenario (default: data/seeds)")
    c.add_argument("--config", default="moving", help="training YAML or a name in configs/train (default: moving)")
    c.add_argument("--runs", default="runs", help="where training runs go (default: runs)")
    c.add_argument("--out", help="report folder (default: reports/compare-<dataset>; reports/compare-seeds with --scenario)")
    add_model_options(c)

    rp = _verb(sub, "reproduce", "models:cmd_reproduce", help="the paper's Sec. V on the simulated rig, SVM and network side by side",
               description="Simulate every dataset the paper's experiments need (cached under OUT/data), train both models, write PNG "
                           "figures and report.md with the paper's numbers beside ours.")
    rp.add_argument("--out", default="reports/reproduce", help="report folder (default: reports/reproduce)")
    rp.add_argument("--quick", action="store_true", help="small datasets and short training: a few minutes on 2 cores (default: full size)")
    rp.add_argument("--seeds", type=nonneg_int, nargs="+", metavar="K",
                    help="simulator seeds, each another simulated link and presses (default: 0 1 quick, 0 1 2 full)")
    rp.add_argument("--rig", default="jaco", help="the simulated rig, a name (jaco, fast) or a YAML path (default: jaco)")
    rp.add_argument("--only", nargs="+", choices=REPRODUCE_EXPERIMENTS, metavar="EXP",
                    help=f"run these experiments only, one of {', '.join(REPRODUCE_EXPERIMENTS)} (default: all)")
    rp.add_argument("--jobs", type=positive_int, metavar="N",
                    help="worker processes: datasets, then seeds and experiments, side by side (default: the cores divided by --threads, "
                         "at most 4)")


def _device_verbs(sub) -> None:
    lv = _verb(sub, "live", "live:cmd_live", help="real-time touch sensing: audio -> touch events (JSON lines)",
               description="Run the live loop. By default on the simulated device with scripted touches; --device NAME|INDEX uses a real "
                           "audio interface (see `sonicskin devices`). Touch events go to stdout as JSON lines, a summary to stderr at "
                           "the end. Without --artifact on the simulated device, an SVM is trained first, once: it takes about 2 min (the "
                           "stationary scenario, an idle 2-core machine), writes about 200 MB of simulated recordings to "
                           "./data/sim-SCENARIO-oneshot and the artifact to ./artifacts/sim-SCENARIO-svm, which later runs reuse; a line "
                           "on stderr says so before it starts. The run stops with one line when the device stops delivering "
                           "(--watchdog), or when its input holds no usable chirp (silent, NaN, clipped, constant, or noise without the "
                           "chirp).")
    _device_options(lv)
    lv.add_argument("--artifact", help="artifact folder (sonicskin export / fit-svm) (default: on the simulated device, an SVM is trained "
                                       "on the spot the first time, about 2 min and 200 MB under ./data and ./artifacts, and reused "
                                       "later)")
    lv.add_argument("--model", metavar="KIND", help="which model of the artifact: svm (the paper's), lda (the closed-form LDA) or net "
                                                    "(the network) (default: svm)")
    lv.add_argument("--scenario", help="simulated device: scenario of the link and the touches (default: stationary)")
    lv.add_argument("--rig", help="rig name or YAML path (default: the --artifact's own rig, else jaco)")
    lv.add_argument("--duration", type=positive_float, default=30.0,
                    help="seconds to run, by the clock (--fast: seconds of simulated stream) (default: 30)")
    lv.add_argument("--udp", type=udp_target, metavar="[HOST:]PORT",
                    help="also send events as UDP datagrams; host defaults to 127.0.0.1 (default: off)")
    lv.add_argument("--lsl", metavar="NAME", nargs="?", const="sonicskin",
                    help="also publish events as a Lab Streaming Layer string stream of this name (needs pylsl: pip install "
                         "'sonicskin[lsl]') (default: off; NAME defaults to sonicskin)")
    lv.add_argument("--watchdog", type=positive_float, default=3.0, metavar="S",
                    help="stop with an error when the device (or the simulated one, --fast too) delivers no audio, or no usable chirp, "
                         "for S seconds (default: 3)")
    lv.add_argument("--fast", action="store_true", help="simulated device: run faster than real time (default: real time)")
    lv.add_argument("--realtime", action="store_true",
                    help="real-time scheduling (SCHED_FIFO where permitted, e.g. as root; else a higher priority) of the audio "
                         "and processing threads, for a busy robot PC; one line on stderr says what was granted (default: off)")
    lv.add_argument("--drop-every", type=positive_int, metavar="N",
                    help="simulated device: drop one audio block in N (N >= 2), fault injection (default: none)")
    lv.add_argument("--no-status", action="store_true", help="no status line on stderr (default: one a second)")
    lv.add_argument("--links", metavar="NAME",
                    help="several links on one interface: a links config with --device and one --link-artifact per link (e.g. "
                         "two-links-time), or an arm file (e.g. arm6, or the ART/arm.yaml that `fit-svm --links` writes): its links "
                         "simulated on the default device, events in each link's frame (`sonicskin info` lists them) (default: one link, "
                         "--tx/--rx)")
    lv.add_argument("--view", metavar="PORT", nargs="?", const="0",
                    help="show the skin live in a browser at http://127.0.0.1:PORT/ (every link unrolled to scale, the touch and its "
                         "force, the last events, the reference and drift state); PORT omitted: any free port, printed on stderr "
                         "(default: off)")
    lv.add_argument("--mcap", metavar="FILE",
                    help="with --links on an arm: also write every touch as ROS 2 messages (contact point and wrench in the link's frame, "
                         "markers) into the MCAP file FILE, for `ros2 bag play` and Foxglove (docs/robot-frame.md) (default: off)")
    lv.add_argument("--ros2", metavar="DOMAIN", nargs="?", const=True,
                    help="with --links on an arm: publish the same messages live as ROS 2 topics over DDS on this domain (needs "
                         "pip install 'sonicskin[ros]'; docs/robot-frame.md) (default: off; DOMAIN: ROS_DOMAIN_ID, else 0)")
    lv.add_argument("--foxglove", metavar="PORT", nargs="?", const=True,
                    help="with --links on an arm: serve the same messages live to Foxglove at ws://127.0.0.1:PORT (needs pip install "
                         "'sonicskin[ros]'; layout: configs/arms/arm6.foxglove.json) (default: off; PORT: 8765, 0 any free)")
    lv.add_argument("--overwrite", action="store_true", help="replace an existing --mcap file (default: refuse it)")
    lv.add_argument("--link-artifact", action="append", metavar="DIR",
                    help="with --links: the artifact of each link, once per link in the config's order (default: none)")
    ck = _verb(sub, "check", "live:cmd_check", help="rig check: chirp, delay, level, SNR, PWM lines, repeatability, touch contrast",
               description="Play the rig's chirp, record every input, ask for one firm press, and print one table: each measurement with "
                           "pass/warn/fail and its fix. Writes check.png (|H(f)| at rest and pressed, noise floor, PWM bands, the band "
                           "used) and check.json to --out. Exit code 0 when nothing fails, 1 otherwise. Runs on the simulated device by "
                           "default.")
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
    _verb(sub, "devices", "data:cmd_devices", help="list audio devices",
               description="List the audio interfaces PortAudio sees (index, name, host API, input and output channels, default rate), "
                           "for `sonicskin live/record --device NAME|INDEX`. Needs libportaudio2; the simulated device needs none.")
    i = _verb(sub, "info", "data:cmd_info", help="show the version, the rig and the available configs",
              description="Print the package version, the rig's sample rate, chirp, period and usable bins, and the names of the shipped "
                          "rig, scenario, training and links configs (usable as --rig/--scenario/--config NAME, and `live --links NAME`).")
    i.add_argument("--rig", default="jaco", help="rig name or YAML path (default: jaco)")


class Parser(argparse.ArgumentParser):
    """An argparse parser whose usage errors are one line (``sonicskin <verb>: error: ...``, exit 2)."""

    def error(self, message: str):  # noqa: D102 - argparse API
        self.exit(2, f"{self.prog}: error: {message} (see `{self.prog} --help`)\n")


class _LightningHelp(argparse.Action):
    """``train -h``: our options, then LightningCLI's model/data/trainer options (:func:`.train.lightning_help`)."""

    def __init__(self, option_strings, dest, **kw):
        super().__init__(option_strings, dest, nargs=0, default=argparse.SUPPRESS, help="show this help (with the LightningCLI "
                                                                                        "model/data/trainer options) and exit")

    def __call__(self, parser, namespace, values, option_string=None):
        parser.print_help()
        sys.stdout.flush()
        if importlib.util.find_spec("lightning") is None:
            print("\n(LightningCLI options appear here with the training extra: pip install 'sonicskin[train]')")
        else:
            verb_function("train:lightning_help")()
        parser.exit(0)


def need_train_extra(verb: str) -> None:
    if not all(importlib.util.find_spec(m) for m in ("torch", "lightning")):
        raise UsageError(f"`sonicskin {verb}` needs the training extra: pip install -c constraints.txt 'sonicskin[train]'")


def verb_function(spec: str, verb: str = "train"):
    """The function ``"module:function"`` of this package's CLI, imported now (the torch verbs need the training extra)."""
    module, _, name = spec.partition(":")
    if module == "train":
        need_train_extra(verb)
    return getattr(importlib.import_module(f"{__package__}.{module}"), name)


def build_parser() -> argparse.ArgumentParser:
    p = Parser(prog="sonicskin", description="SonicSkin: touch localization and force from one pair of piezo discs on a robot link. Runs "
                                             "on the simulated rig by default.",
               epilog=EPILOG, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--version", action="version", version=f"sonicskin {__version__}")
    sub = p.add_subparsers(dest="verb", metavar="<verb>", parser_class=Parser)
    _data_verbs(sub)
    _model_verbs(sub)
    _device_verbs(sub)
    for verb in sub.choices.values():  # one thread setting on every verb (sonicskin.threads)
        verb.add_argument("--threads", metavar="N", default=None,
                          help=f"threads for training, featurisation and simulation (default: ${threads.ENV}, else half "
                               f"the cores, at most 4: {threads.default_threads()} here)")
    return p
