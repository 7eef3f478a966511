"""The verbs without a model: ``simulate``, ``import-wav``, ``import-spectra``, ``info`` and ``devices`` (no
scikit-learn, onnxruntime or matplotlib).  A writer leaves nothing behind when it fails before writing a part."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from .. import __version__
from ..acquire import list_devices
from ..errors import UsageError
from ..importers import import_spectra, import_wav
from ..links import load_arm
from ..rig import Rig, config_names
from ..sim import generate
from ..sim.scenario import Scenario
from ._common import clean_on_failure, writer_mode


def cmd_simulate(a: argparse.Namespace) -> int:
    if a.links:
        return _simulate_arm(a)
    sc = Scenario.load(a.scenario, seed=a.seed)  # a scenario family (random) draws the rig of that seed
    over = dict(a.set or ())  # checked as the scenario's own keys (Scenario.from_dict)
    if a.sessions is not None:
        over["sessions"] = a.sessions
    if over:
        sc = Scenario.from_dict({**sc.to_dict(), **over})
    rig = Rig.load(a.rig or "jaco")
    out = Path(a.out or f"data/{sc.name}")
    mode = writer_mode(a)
    with clean_on_failure(out, mode):
        generate.simulate_dataset(sc, rig, out, mode=mode, progress=not a.quiet)
    print(f"dataset written to {out}")
    return 0


def _simulate_arm(a: argparse.Namespace) -> int:
    """``simulate --links ARM``: one dataset per simulated link of an arm file, ``OUT/<link>``."""
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
            generate.simulate_dataset(sc, lk.rig or rig, out, mode=mode, progress=not a.quiet)
    print(f"{len(links)} link datasets written to {root}/<link> ({', '.join(lk.name for lk in links)})")
    return 0


def cmd_import_wav(a: argparse.Namespace) -> int:
    # The importer writes into a hidden folder and moves it into place only when complete.
    import_wav(a.wav_dir, a.labels, a.out, sweep_wav=a.sweep, chirp_hz=tuple(a.chirp) if a.chirp else None,
               period_s=a.period, amplitude=a.amplitude, channel=a.channel, pwm_hz=tuple(a.pwm_hz or ()),
               pwm_halfwidth_hz=a.pwm_halfwidth, mode=writer_mode(a))
    return 0


def cmd_import_spectra(a: argparse.Namespace) -> int:
    import_spectra(a.table, a.out, rig=Rig.load(a.rig) if a.rig else None, fs_hz=a.fs, frame=a.frame, linear=a.linear, mode=writer_mode(a))
    return 0


def cmd_devices(a: argparse.Namespace) -> int:
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
        names = config_names(kind)
        if names:
            print(f"{kind}: {', '.join(names)}")
    return 0
