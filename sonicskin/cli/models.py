"""The model verbs that need no torch: ``evaluate``, ``fit-svm``, ``compare`` and ``reproduce``.  ``compare``
without ``--artifact`` trains the network through :mod:`.train`, loaded only then."""

from __future__ import annotations

import argparse
import copy
import json
import sys
from pathlib import Path

import numpy as np

from ..compare import compare_artifact, format_comparison, save_comparison
from ..dataset import Dataset, link_wall, other_wall, wall_record
from ..errors import UsageError
from ..evaluate import evaluate_svm, format_report, save_report
from ..fit import build_svm_artifact, selection_lines
from ..links import load_arm, missing_datasets, write_arm
from ..reproduce import reproduce
from ..rig import Layout, Rig
from ..seeds import compare_seeds, format_markdown
from ..session import arm_file_of
from ._common import alg2_options, check_split_options, removed_on_failure, resolve_n_bins
from .parser import need_train_extra, verb_function

#: the options that choose how models train (refused where the models are already trained)
TRAINING_OPTIONS = ("n_bins", "mode", "train", "test_subjects", "alpha_s", "beta_s")


def _sessions_for_test(a: argparse.Namespace, data: str | Path) -> tuple[list[str] | None, list[str] | None]:
    """``--train/--val/--test`` as the train and val sessions that leave exactly ``--test`` to test on."""
    sessions = Dataset(data).sessions
    unknown = sorted((set(a.test or ()) | set(a.train or ()) | set(a.val or ())) - set(sessions))
    if unknown:
        raise UsageError(f"session(s) {', '.join(unknown)} are not in {data} (it has {', '.join(sessions)})")
    if not a.test:
        return a.train, a.val
    rest = [s for s in sessions if s not in a.test]
    train = a.train or rest[:1]
    if not train:
        raise UsageError(f"--test takes every session of {data}; leave at least one to train on")
    val = a.val if a.val is not None else [s for s in rest if s not in train]
    return list(train), list(val)


def cmd_evaluate(a: argparse.Namespace) -> int:
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
        table = table.select(~np.isin(table["session"], out_of_split))
    out = Path(a.out or Path("reports") / ds.root.name)
    res = evaluate_svm(ds, train_sessions=train, table=table, ablations=not a.no_ablations, n_bins=n_bins,
                       mode=a.mode or "relative", val_sessions=val or (), artifact=out / "artifact", **alg2_options(a))
    print(format_report(res))
    paths = save_report(res, out, ds.layout)
    print("wrote " + ", ".join(str(p) for p in paths) + f" and the paper's SVM as deployed, {out / 'artifact'}")
    return 0


def cmd_fit_svm(a: argparse.Namespace) -> int:
    check_split_options(a)
    if a.val or a.test or a.test_subjects:
        raise UsageError("fit-svm trains the deployment model on every session it is given, without validation or "
                         "test split; choose them with --train (test it with `sonicskin compare --artifact`)")
    if a.links:
        return _fit_svm_arm(a)
    n_bins = resolve_n_bins(a, a.data) if a.n_bins is not None else None  # None: chosen by validation
    with removed_on_failure(a.out):
        build_svm_artifact(a.data, a.out, n_bins=n_bins, mode=a.mode or "relative", train_sessions=a.train, **alg2_options(a))
    return 0


def _fit_svm_arm(a: argparse.Namespace) -> int:
    """``fit-svm --links ARM --data DIR --out ART``: one artifact per link (DIR/<link> -> ART/<link>) and ART/arm.yaml."""
    rig, links = load_arm(a.links)
    data, out = Path(a.data), Path(a.out)
    if (out / "skin.json").exists():  # the arm's files would sit beside it, and `live --artifact OUT` would run the arm
        raise UsageError(f"{out} holds a single-link artifact (skin.json); an arm's artifacts written there would mix with "
                         f"it: choose an empty or new --out")
    absent = missing_datasets(links, data)
    if absent:
        raise UsageError(f"{data} has no dataset for links {absent} (expected {data}/<link>/dataset.json); record or "
                         f"simulate every link first (`sonicskin simulate --links {a.links} --out {data}`)")
    for lk in links:  # a simulated link's data is of its own wall (live refuses an artifact of another)
        ds = Dataset(data / lk.name)
        what = lk.scenario and other_wall(wall_record(ds.meta.get("source"), ds.rig, ds.layout),
                                          link_wall(lk.scenario, ds.rig, ds.layout), "this link's")
        if what:
            raise UsageError(f"link {lk.name!r}: {data / lk.name} was recorded on {what}; simulate this arm's links "
                             f"first (`sonicskin simulate --links {a.links} --out DIR`) and train on DIR")
    n_bins = None if a.n_bins is None else resolve_n_bins(a, data / links[0].name)
    arts = {}
    for lk in links:
        print(f"link {lk.name}: training on {data / lk.name}", file=sys.stderr)
        with removed_on_failure(out / lk.name):
            build_svm_artifact(data / lk.name, out / lk.name, n_bins=n_bins, mode=a.mode or "relative",
                               train_sessions=a.train, training={"link": {"name": lk.name, "frame": lk.frame}},
                               **alg2_options(a))
        arts[lk.name] = out / lk.name
    path = write_arm(a.links, out, arts, rig)
    print(f"arm file written to {path}: run it with `sonicskin live --links {path}`")
    return 0


def cmd_compare(a: argparse.Namespace, extra: list[str]) -> int:
    """``compare``: ``--scenario`` (simulated), ``--data --artifact`` (score an artifact) or ``--data`` (train and score)."""
    if a.scenario:
        return _compare_scenarios(a)
    if a.links:
        return _compare_arm(a, extra)
    _check_compare_data(a)
    return _compare_artifact(a, extra) if a.artifact is not None else _compare_trained(a, extra)


def _compare_trained(a: argparse.Namespace, extra: list[str]) -> int:
    return verb_function("train:compare_trained", "compare")(a, extra)


def _compare_arm(a: argparse.Namespace, extra: list[str]) -> int:
    """``--links ARM --data DIR``: ``compare`` on every link, one report per link under ``OUT/<link>``."""
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
    out = Path(a.out or "reports/compare-seeds")
    check_split_options(a)
    if a.train or a.test or a.test_subjects or (a.val and a.val != ["s001"]):
        raise UsageError("--scenario splits each scenario itself: the first session trains, the others test; --val s001 "
                         "validates on the second and refits on both (drop --train/--test/--test-subjects)")
    if a.alpha_s is not None or a.beta_s is not None:
        raise UsageError("--scenario trains with Alg. 2's defaults; --alpha-s/--beta-s are for --data")
    res = compare_seeds(a.scenario, sim_seeds=a.sim_seeds, train_seeds=a.train_seeds, cache=a.cache, out=out,
                        epochs=a.epochs, rig=Rig.load(a.rig or "jaco"), val=bool(a.val))
    print(format_markdown(res))
    print(f"wrote {out}/seeds.json, seeds.md, seeds.png")
    return 0


def _check_compare_data(a: argparse.Namespace) -> None:
    """What ``--data`` (with or without ``--artifact``) refuses before anything trains or loads."""
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
    if (extra or any(getattr(a, k) is not None for k in TRAINING_OPTIONS) or a.val is not None or not a.refit or a.config != "moving"):
        raise UsageError("with --artifact the models are already trained; only --test chooses the sessions to "
                         "compare on (drop the training options or --artifact)")
    return _score_artifact(a, artifact, expected=True)


def _score_artifact(a: argparse.Namespace, artifact: Path, *, expected: bool) -> int:
    """Replay the test sessions through ``artifact``, print and write the comparison (``expected``: selection's estimate)."""
    res = compare_artifact(artifact, a.data, sessions=a.test)
    title = f"{Path(a.data).name}: " + " vs ".join(res["labels"][k] for k in res["models"])
    print(format_comparison(res, title))
    meta = json.loads((artifact / "skin.json").read_text())
    if expected and meta.get("selection"):  # what the validation expected, next to what the test sessions gave
        print("\n".join(f"  expected at training: {line}" for line in selection_lines(meta["selection"])))
    out = Path(a.out or Path("reports") / f"compare-{Path(a.data).name}")
    paths = save_comparison(res, out, Layout.from_dict(meta["layout"]), title)
    print("wrote " + ", ".join(str(p) for p in paths))
    return 0


def cmd_reproduce(a: argparse.Namespace) -> int:
    reproduce(a.out, quick=a.quick, seeds=a.seeds, only=a.only, rig=Rig.load(a.rig), jobs=a.jobs)
    return 0
