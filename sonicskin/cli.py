"""``sonicskin <verb>``: one command line for the simulated rig, datasets and models."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import yaml

from . import __version__

EPILOG = """\
typical session on the simulated rig:
  sonicskin simulate --scenario moving --out data/moving
  sonicskin evaluate --data data/moving --out reports/moving
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

    i = sub.add_parser("info", help="show the rig and the available configs")
    i.add_argument("--rig", default="jaco")
    i.set_defaults(func=cmd_info)
    return p


def main(argv: list[str] | None = None) -> int:
    p = build_parser()
    a = p.parse_args(argv)
    if not getattr(a, "func", None):
        p.print_help()
        return 2
    try:
        return a.func(a)
    except (ValueError, FileNotFoundError, FileExistsError) as exc:  # user errors: one clear line, no traceback
        print(f"sonicskin {a.verb}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"\nsonicskin {a.verb}: interrupted; everything written so far is kept", file=sys.stderr)
        return 130


if __name__ == "__main__":
    raise SystemExit(main())
