"""Verbs that train, export and score models: ``evaluate``, ``fit-svm``, ``train``, ``export``,
``compare``, ``reproduce``.  The first five share one set of model/split options
(:func:`._common.add_model_options`)."""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
from pathlib import Path

from ..errors import UsageError
from ._common import (
    add_model_options,
    check_split_options,
    latest_checkpoint,
    lightning_overrides,
    need_train_extra,
    nonneg_int,
    positive_int,
    removed_on_failure,
    resolve_n_bins,
    train_config,
)

# sonicskin.reproduce.EXPERIMENTS, spelled out so that building the parser does not import the simulator (4 s)
REPRODUCE_EXPERIMENTS = ("fig6b", "fig11", "fig12", "fig13", "table1", "fig16")


def _sessions_for_test(a: argparse.Namespace, data: str | Path) -> tuple[list[str] | None, list[str] | None]:
    """``--train/--val/--test`` as the train and val sessions that leave exactly ``--test`` to test on
    (the split code tests on every session not trained or validated on)."""
    if not a.test:
        return a.train, a.val
    from ..dataset import Dataset

    sessions = Dataset(data).sessions
    unknown = sorted((set(a.test) | set(a.train or ()) | set(a.val or ())) - set(sessions))
    if unknown:
        raise UsageError(f"session(s) {', '.join(unknown)} are not in {data} (it has {', '.join(sessions)})")
    rest = [s for s in sessions if s not in a.test]
    train = a.train or rest[:1]
    if not train:
        raise UsageError(f"--test takes every session of {data}; leave at least one to train on")
    val = a.val if a.val is not None else [s for s in rest if s not in train]
    return list(train), list(val)


def cmd_evaluate(a: argparse.Namespace) -> int:
    from ..dataset import Dataset
    from ..evaluate import evaluate_svm, format_report, save_report

    check_split_options(a)
    if a.test_subjects:
        raise UsageError("evaluate trains one-shot on sessions; --test-subjects is for train/compare "
                         "(use --train/--test here)")
    ds = Dataset(a.data)
    n_bins = resolve_n_bins(a, a.data)
    train, val = _sessions_for_test(a, a.data)
    table = ds.features()
    # held out: the SVM has no validation step; with --test, exactly those sessions are tested (not every other one)
    out_of_split = list(val or ()) + [s for s in ds.sessions if a.test and s not in {*train, *(val or ()), *a.test}]
    if out_of_split:
        import numpy as np

        table = table.select(~np.isin(table["session"], out_of_split))
    out = Path(a.out or Path("reports") / ds.root.name)
    res = evaluate_svm(ds, train_sessions=train, table=table, ablations=not a.no_ablations, n_bins=n_bins,
                       mode=a.mode or "relative", val_sessions=val or (), artifact=out / "artifact")
    print(format_report(res))
    paths = save_report(res, out, ds.layout)
    print("wrote " + ", ".join(str(p) for p in paths) + f" and the paper's SVM as deployed, {out / 'artifact'}")
    return 0


def cmd_fit_svm(a: argparse.Namespace) -> int:
    from ..fit import build_svm_artifact

    check_split_options(a)
    if a.val or a.test or a.test_subjects:
        raise UsageError("fit-svm trains the deployment model on every session it is given, without validation or "
                         "test split; choose them with --train (test it with `sonicskin compare --artifact`)")
    if a.links:
        return _fit_svm_arm(a)
    n_bins = resolve_n_bins(a, a.data) if a.n_bins is not None else None  # None: chosen by validation
    with removed_on_failure(a.out):
        build_svm_artifact(a.data, a.out, n_bins=n_bins, mode=a.mode or "relative", train_sessions=a.train)
    return 0


def _fit_svm_arm(a: argparse.Namespace) -> int:
    """``fit-svm --links ARM --data DIR --out ART``: one artifact per link (DIR/<link> -> ART/<link>) and ART/arm.yaml,
    the arm file that lists them (``live --links ART/arm.yaml``)."""
    from ..fit import build_svm_artifact
    from ..links import load_arm, missing_datasets, write_arm

    rig, links = load_arm(a.links)
    data, out = Path(a.data), Path(a.out)
    absent = missing_datasets(links, data)
    if absent:
        raise UsageError(f"{data} has no dataset for links {absent} (expected {data}/<link>/dataset.json); record or "
                         f"simulate every link first (`sonicskin simulate --links {a.links} --out {data}`)")
    n_bins = None if a.n_bins is None else resolve_n_bins(a, data / links[0].name)
    arts = {}
    for lk in links:
        print(f"link {lk.name}: training on {data / lk.name}", file=sys.stderr)
        with removed_on_failure(out / lk.name):
            build_svm_artifact(data / lk.name, out / lk.name, n_bins=n_bins, mode=a.mode or "relative",
                               train_sessions=a.train)
        arts[lk.name] = out / lk.name
    path = write_arm(a.links, out, arts, rig)
    print(f"arm file written to {path}: run it with `sonicskin live --links {path}`")
    return 0


def _train_args(a: argparse.Namespace, data: str | None, extra: list[str]) -> list[str]:
    check_split_options(a)
    if data:
        from ..dataset import Dataset

        Dataset(data)  # refused here, in one line, before Lightning starts
    n_bins = resolve_n_bins(a, data) if data and a.n_bins is not None else a.n_bins  # None: chosen by validation
    if data and a.test:
        a.train, a.val = _sessions_for_test(a, data)
    return ["--config", train_config(a.config)] + (["--data.data", data] if data else []) + lightning_overrides(a, n_bins) + extra


def cmd_train(a: argparse.Namespace, extra: list[str]) -> int:
    need_train_extra("train")
    from sonicskin.training.cli import main as train_main

    cli = train_main(_train_args(a, a.data, extra))
    if not cli.trainer.is_global_zero:  # DDP: rank zero reports
        return 0
    _report_training(cli)
    ckpt = cli.trainer.checkpoint_callback
    best = ckpt.best_model_path or "none: no validation ran, export takes last.ckpt"
    print(f"checkpoints: {ckpt.dirpath} (best {best}); config saved beside them")
    return 0


def _report_training(cli, *, selection: bool = True) -> None:
    res = getattr(cli, "epoch_bar", None) and cli.epoch_bar.results
    if res:
        prep = getattr(cli.datamodule, "prepared", None)  # no finite force anywhere: RMSE 0 would be a made-up number
        no_force = prep is not None and not any(v == v for v in prep.force.tolist())
        metrics = ", ".join(f"{k} n/a (no force sensor)" if no_force and "force" in k else f"{k} {v:.3f}"
                            for k, v in res.items() if k.startswith("val_"))
        split = getattr(prep, "split", None)
        if split is not None:  # say where the val_ metrics come from (no validation session: the training data)
            metrics += (f" (validation {', '.join(split.val)})" if split.val else
                        f" (no validation session: on the training sessions {', '.join(split.train)})")
        print(f"trained {res['epochs']} epochs in {res['train_time_s']:.0f} s: {metrics}")
    from ..fit import selection_lines

    for line in selection_lines(getattr(cli.datamodule, "selection", None) if selection else None):
        print(line)


def cmd_export(a: argparse.Namespace) -> int:
    check_split_options(a)
    if any(getattr(a, k) for k in ("n_bins", "mode", "train", "val", "test", "test_subjects")):
        raise UsageError("export keeps the bins, inputs and split the checkpoint was trained with; "
                         "pass --n-bins/--mode/--train/... to `sonicskin train` (or use `sonicskin compare`)")
    run = Path(a.run)
    if not run.exists():
        raise FileNotFoundError(f"{run} does not exist; pass a run folder of `sonicskin train` or its .ckpt file")
    need_train_extra("export")
    export_quietly(latest_checkpoint(run), a.out, data=a.data, refit=a.refit)
    return 0


def export_quietly(ckpt: Path, out: str | Path, *, data: str | Path | None, refit: bool = True) -> None:
    """:func:`sonicskin.training.fit.artifact_from_checkpoint` with one result line: torch.onnx's progress prints and third-party
    warnings are dropped, a half-made artifact is removed, an unreadable checkpoint is one line (training.checkpoint refuses it)."""
    import io
    import sys

    from sonicskin.training.cli import quiet_third_party
    from sonicskin.training.fit import artifact_from_checkpoint

    stdout = sys.stdout
    with removed_on_failure(out), quiet_third_party(), contextlib.redirect_stdout(io.StringIO()):
        artifact_from_checkpoint(ckpt, out, data=data, refit=refit, log=lambda msg: print(msg, file=stdout))


def cmd_compare(a: argparse.Namespace, extra: list[str]) -> int:
    """``compare``: one verb, three entry points: ``--scenario`` (simulated datasets over seeds), ``--data`` with
    ``--artifact`` (score a trained artifact) and ``--data`` alone (train both models, export, score)."""
    if a.scenario:
        return _compare_scenarios(a)
    if a.links:
        return _compare_arm(a, extra)
    _check_compare_data(a)
    return _compare_artifact(a, extra) if a.artifact is not None else _compare_trained(a, extra)


def _compare_arm(a: argparse.Namespace, extra: list[str]) -> int:
    """``--links ARM --data DIR``: ``compare`` on every link (``DIR/<link>``; with ``--artifact ART``, the trained arm
    folder or its arm.yaml, each link's artifact), one report per link under ``OUT/<link>``."""
    import copy

    from ..links import load_arm, missing_datasets
    from ..session import arm_file_of

    if not a.data:
        raise UsageError(f"compare --links {a.links} needs --data DIR, the folder of the links' datasets (DIR/<link>: "
                         f"`sonicskin simulate --links {a.links} --out DIR`)")
    spec = a.links
    if a.artifact is not None:  # the trained arm: its links carry their artifacts
        spec = arm_file_of(a.artifact)
        if spec is None:
            raise UsageError(f"--artifact {a.artifact} with --links: give the trained arm (the folder `fit-svm --links` "
                             f"wrote, holding arm.yaml)")
    _, links = load_arm(spec)
    data = Path(a.data)
    absent = missing_datasets(links, data)
    if absent:
        raise UsageError(f"{data} has no dataset for links {absent} (expected {data}/<link>/dataset.json)")
    out = Path(a.out or Path("reports") / f"compare-{Path(str(a.links)).stem}")
    for lk in links:
        print(f"## link {lk.name}", flush=True)
        b = copy.copy(a)
        b.links, b.data, b.out = None, str(data / lk.name), str(out / lk.name)
        b.artifact = None if a.artifact is None else str(lk.artifact)
        _check_compare_data(b)
        (_compare_artifact(b, extra) if b.artifact is not None else _compare_trained(b, extra))
    print(f"wrote one report per link under {out}/<link>")
    return 0


def _compare_scenarios(a: argparse.Namespace) -> int:
    """``--scenario``: simulated scenarios over several simulator and training seeds, with the paired interval."""
    if a.data or a.artifact:
        raise UsageError("--scenario simulates its own datasets; drop --data/--artifact (or drop --scenario)")
    need_train_extra("compare --scenario")
    from ..rig import Rig
    from ..seeds import compare_seeds, format_markdown

    out = Path(a.out or "reports/compare-seeds")
    check_split_options(a)
    if a.train or a.test or a.test_subjects or (a.val and a.val != ["s001"]):
        raise UsageError("--scenario splits each scenario itself: the first session trains, the others test; --val s001 "
                         "validates on the second and refits on both (drop --train/--test/--test-subjects)")
    res = compare_seeds(a.scenario, sim_seeds=a.sim_seeds, train_seeds=a.train_seeds, cache=a.cache, out=out,
                        epochs=a.epochs, rig=Rig.load(a.rig or "jaco"), val=bool(a.val))
    print(format_markdown(res))
    print(f"wrote {out}/seeds.json, seeds.md, seeds.png")
    return 0


def _check_compare_data(a: argparse.Namespace) -> None:
    """What ``--data`` (with or without ``--artifact``) refuses before anything trains or loads."""
    from ..dataset import Dataset

    if a.rig:
        raise UsageError("--rig chooses the simulated rig of --scenario; a dataset (--data) carries its own rig")
    if a.epochs is not None:  # was ignored: the network trained for the config's epochs
        raise UsageError("--epochs sets the network epochs of --scenario runs; with --data pass --trainer.max_epochs N "
                         "(or drop it with --artifact)")
    if not a.data:
        raise UsageError("give --data DATASET (one dataset) or --scenario NAME... (simulated, several seeds)")
    check_split_options(a)  # --val none -> no validation session
    Dataset(a.data)  # a bad dataset is refused before anything trains


def _compare_artifact(a: argparse.Namespace, extra: list[str]) -> int:
    """``--data --artifact``: score a trained artifact on the test sessions (``--test``, default its split's)."""
    artifact = Path(a.artifact)
    if not (artifact / "skin.json").is_file():
        raise FileNotFoundError(f"{artifact} is not a sonicskin artifact (no skin.json there); create one with "
                                f"`sonicskin export` or `sonicskin fit-svm`, or drop --artifact to train both models")
    if (extra or any(getattr(a, k) for k in ("n_bins", "mode", "train", "test_subjects")) or a.val is not None or not a.refit
            or a.config != "moving"):
        raise UsageError("with --artifact the models are already trained; only --test chooses the sessions to "
                         "compare on (drop the training options or --artifact)")
    return _score_artifact(a, artifact, expected=True)


def _compare_trained(a: argparse.Namespace, extra: list[str]) -> int:
    """``--data``: train and export both models on the same split, then score the artifact."""
    need_train_extra("compare")
    from sonicskin.training.cli import main as train_main

    run = Path(a.runs) / f"compare-{Path(a.data).name}"
    args = _train_args(a, a.data, ["--trainer.default_root_dir", str(run),
                                   "--trainer.logger.init_args.save_dir", str(run)] + extra)
    cli = train_main(args)
    if not cli.trainer.is_global_zero:  # DDP: rank zero exports and compares
        return 0
    _report_training(cli, selection=False)  # the export below prints the whole selection
    artifact = run / "artifact"
    export_quietly(latest_checkpoint(Path(cli.trainer.checkpoint_callback.dirpath)), artifact, data=a.data, refit=a.refit)
    return _score_artifact(a, artifact, expected=False)


def _score_artifact(a: argparse.Namespace, artifact: Path, *, expected: bool) -> int:
    """Replay the test sessions (exactly ``--test`` when given: the split tests every session it does not train or
    validate on) through ``artifact``; print and write the comparison.  ``expected``: print what model selection
    expected at training beside it."""
    from ..compare import compare_artifact, format_comparison, save_comparison
    from ..rig import Layout

    res = compare_artifact(artifact, a.data, sessions=a.test)
    title = f"{Path(a.data).name}: " + " vs ".join(res["labels"][k] for k in res["models"])
    print(format_comparison(res, title))
    meta = json.loads((artifact / "skin.json").read_text())
    if expected and meta.get("selection"):  # what the validation expected, next to what the test sessions gave
        from ..fit import selection_lines

        print("\n".join(f"  expected at training: {line}" for line in selection_lines(meta["selection"])))
    out = Path(a.out or Path("reports") / f"compare-{Path(a.data).name}")
    paths = save_comparison(res, out, Layout.from_dict(meta["layout"]), title)
    print("wrote " + ", ".join(str(p) for p in paths))
    return 0


def cmd_reproduce(a: argparse.Namespace) -> int:
    from ..reproduce import reproduce
    from ..rig import Rig

    reproduce(a.out, quick=a.quick, seeds=a.seeds, only=a.only, rig=Rig.load(a.rig), jobs=a.jobs)
    return 0


def add_parsers(sub) -> None:
    e = sub.add_parser("evaluate", help="train the paper's SVM system on a dataset and report its accuracy",
                       description="Train OSPA + RBF SVM + Alg. 2 + Fourier force on the first session (one-shot), "
                                   "test on the others; print the paper's metrics and ablations; write JSON and PNG. "
                                   "--mode relative calibrates the scores online (Alg. 2); absolute keeps the training "
                                   "session's reference throughout.")
    e.add_argument("--data", required=True, help="dataset folder")
    e.add_argument("--out", help="report folder (default: reports/<dataset name>)")
    e.add_argument("--no-ablations", action="store_true",
                   help="skip the no-OSPA / no-calibration / total-energy runs (default: run them)")
    add_model_options(e)
    e.set_defaults(func=cmd_evaluate)

    f = sub.add_parser("fit-svm", help="SVM-only artifact from a recording, no torch needed",
                       description="The paper's system as a deployment artifact (svm.onnx + skin.json), trained on "
                                   "every session of a dataset (or --train) on a machine without torch.")
    f.add_argument("--data", required=True, help="dataset folder (with --links: one dataset per link, DATA/<link>)")
    f.add_argument("--out", required=True, help="artifact folder to write (with --links: OUT/<link> and OUT/arm.yaml)")
    f.add_argument("--links", metavar="ARM", help="an arm file: one artifact per link and the arm file that lists them "
                                                  "(default: one link)")
    add_model_options(f, train_default="all")
    f.set_defaults(func=cmd_fit_svm)

    t = sub.add_parser("train", help="train the network (Lightning; any --trainer.* / --model.* / --data.* override)",
                       description="Train SkinNet jointly for location and force with LightningCLI. Options not "
                                   "listed here go to LightningCLI, e.g. --trainer.max_epochs 5 --model.hidden '[64, 64]' "
                                   "--data.batch_size 64; their full list (model, data, trainer) follows below when "
                                   "the training extra is installed.")
    t.add_argument("--config", default="moving", help="training YAML or a name in configs/train (default: moving)")
    t.add_argument("--data", help="dataset folder (default: data.data of the config)")
    add_model_options(t)
    t.set_defaults(func=cmd_train, passthrough=True, lightning_help=True)

    x = sub.add_parser("export", help="export the network and the SVM baseline into one ONNX artifact",
                       description="Write a deployment artifact from a training run: net.onnx (the network), svm.onnx "
                                   "(the paper's SVM, trained here on the run's own split and bins) and skin.json "
                                   "(rig, layout, bins, calibration, force curves, checksums), each checked for parity "
                                   "against the original. Bins, inputs and split come from the checkpoint.")
    x.add_argument("--run", required=True, help="a checkpoint (.ckpt), or a run folder (its newest best/last checkpoint)")
    x.add_argument("--out", required=True, help="artifact folder to write")
    x.add_argument("--data", help="dataset (default: the one the checkpoint was trained on)")
    add_model_options(x)
    x.set_defaults(func=cmd_export)

    c = sub.add_parser("compare", help="network vs SVM on the same splits: table, JSON and PNG",
                       description="Train + export both models (or load --artifact: a network + SVM artifact, or a "
                                   "`fit-svm` one) and compare them on the test sessions: accuracy, < 2 / < 3 cm, Table I "
                                   "force, detection, ONNX latency, size. The report names the train, validation and test "
                                   "sessions and how many chirps of each location it scored. With --test, exactly those "
                                   "sessions are tested (the rest not in --train validate unless --val says otherwise). "
                                   "Without --artifact, other options go to LightningCLI as in `sonicskin train`.")
    c.add_argument("--data", help="dataset folder (required unless --scenario; with --links: DATA/<link>) (default: none)")
    c.add_argument("--links", metavar="ARM", help="compare every link of an arm file on DATA/<link> (with --artifact: "
                                                  "the trained arm), a report per link in OUT/<link> (default: one link)")
    c.add_argument("--artifact", help="use this artifact instead of training (default: train both models first)")
    c.add_argument("--scenario", nargs="+", metavar="NAME",
                   help="instead of --data: simulate these scenarios with every --sim-seeds, train with every --train-seeds, "
                        "and report mean, std and the paired net - SVM 95 %% interval (e.g. moving stationary; default: none)")
    c.add_argument("--sim-seeds", type=int, nargs="+", default=[0, 1, 2], help="simulator seeds (default: 0 1 2)")
    c.add_argument("--train-seeds", type=int, nargs="+", default=[0, 1], help="network training seeds (default: 0 1)")
    c.add_argument("--epochs", type=int, help="network epochs with --scenario (default: training.quick's)")
    c.add_argument("--rig", help="with --scenario: the simulated rig, a name (jaco, fast) or a YAML path (default: jaco)")
    c.add_argument("--cache", default="data/seeds", help="simulated datasets for --scenario (default: data/seeds)")
    c.add_argument("--config", default="moving", help="training YAML or a name in configs/train (default: moving)")
    c.add_argument("--runs", default="runs", help="where training runs go (default: runs)")
    c.add_argument("--out", help="report folder (default: reports/compare-<dataset>; reports/compare-seeds with --scenario)")
    add_model_options(c)
    c.set_defaults(func=cmd_compare, passthrough=True)

    rp = sub.add_parser("reproduce", help="the paper's Sec. V on the simulated rig, SVM and network side by side",
                        description="Simulate every dataset the paper's experiments need (cached under OUT/data), train "
                                    "both models, write PNG figures and report.md with the paper's numbers beside ours.")
    rp.add_argument("--out", default="reports/reproduce", help="report folder (default: reports/reproduce)")
    rp.add_argument("--quick", action="store_true",
                    help="small datasets and short training: a few minutes on 2 cores (default: full size)")
    rp.add_argument("--seeds", type=nonneg_int, nargs="+", metavar="K",
                    help="simulator seeds, each another simulated link and presses (default: 0 1 quick, 0 1 2 full)")
    rp.add_argument("--rig", default="jaco", help="the simulated rig, a name (jaco, fast) or a YAML path (default: jaco)")
    rp.add_argument("--only", nargs="+", choices=REPRODUCE_EXPERIMENTS, metavar="EXP",
                    help=f"run these experiments only, one of {', '.join(REPRODUCE_EXPERIMENTS)} (default: all)")
    rp.add_argument("--jobs", type=positive_int, metavar="N",
                    help="worker processes: datasets, then seeds and experiments, side by side (default: the cores divided "
                         "by --threads, at most 4)")
    rp.set_defaults(func=cmd_reproduce)
