"""How much the received spectrum changes over the warm-up, and which part of the link makes it.

For a scenario's link (default: ``stationary``, the CFRP Kinova link) at 15 / 30 / 60 / 120 minutes
after power-on, the simulator's own temperature model (:meth:`sonicskin.sim.Simulator.temperatures`:
the warm-up field along the link, split into its mean, its non-uniform Legendre parts and the two
bond temperatures) is switched on one part at a time, and the noise-free received spectrum
``|H(f) T_tx(f) T_rx(f)|`` over the rig's band (the bins the features use: 20-80 kHz without the
PWM notches) is compared with the one at power-on:

- total: everything (what the simulator renders);
- bonds: only the TX and RX hot-melt bonds at their temperatures (wall at ambient);
- wall stretch: only the wall's mean rise (every modal frequency moves, loss factor rises);
- wall non-uniform (Born): the full wall minus the stretched wall (first-order Born terms of the
  field's linear and ends-vs-middle parts: mode shapes change, not only frequencies).

Each figure is the median over the band's frequency bins of ``|change in dB|``.  Stdout: a markdown
table; nothing random (the channel is the scenario's, seeded).

    python benchmarks/thermal_budget.py [--scenario stationary] [--minutes 15 30 60 120] [--small]
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from types import SimpleNamespace

import numpy as np

from sonicskin.rig import Rig
from sonicskin.sim import Scenario, Simulator


def _db(x: np.ndarray) -> np.ndarray:
    return 20 * np.log10(np.abs(x) + 1e-30)


def budget(sim: Simulator, minutes: list[float]) -> list[dict]:
    """One row per time: TX warming (K) and the median |dB change| of the total and of each part."""
    sc = sim.scenario
    t = np.r_[0.0, np.asarray(minutes, float) * 60.0] + 0.0
    tl = SimpleNamespace(time_s=t, temperature_c=sc.temperature_c(t))
    T = sim.temperatures(tl)
    zero = np.zeros_like(T["dT"])
    amb = np.full_like(T["tx_c"], T["tx_c"][0])
    keep = np.isin(sim.channel.bins, sim.rig.band_bins)  # the bins the features use (the channel grid has guard bins)
    wall_full = sim.untouched(T["dT"], T["dT_grad"])[:, keep]
    wall_stretch = sim.untouched(T["dT"])[:, keep]
    wall_0 = sim.untouched(zero)[:, keep]
    bonds = sim.transducers(T["tx_c"], T["rx_c"])[:, keep]
    bonds_0 = sim.transducers(amb, amb)[:, keep]
    total = _db(wall_full * bonds)

    def med(x: np.ndarray, ref: np.ndarray) -> np.ndarray:  # median over the band of |dB change|, per time
        return np.median(np.abs(x[1:] - ref[1:]), axis=1)

    before = _db(wall_0 * bonds_0)  # power-on, every row
    parts = {
        "total": med(total, before),
        "bonds": med(_db(wall_0 * bonds), before),
        "stretch": med(_db(wall_stretch * bonds_0), before),
        "born": med(_db(wall_full), _db(wall_stretch)),
    }
    return [{"minutes": m, "tx_k": float(T["tx_c"][i + 1] - T["tx_c"][0]), "rx_k": float(T["rx_c"][i + 1] - T["rx_c"][0]),
             **{k: float(v[i]) for k, v in parts.items()}} for i, m in enumerate(minutes)]


def _num(x: float) -> str:
    return f"{x:.2g}" if abs(x) < 0.1 else f"{x:.2f}"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0],
                                 epilog="Stdout: the markdown table only; progress on stderr.")
    ap.add_argument("--scenario", default="stationary", help="scenario name or YAML whose link warms up (default: stationary)")
    ap.add_argument("--rig", default="jaco", help="rig name or YAML (default: jaco)")
    ap.add_argument("--minutes", type=float, nargs="+", default=[15, 30, 60, 120], help="times after power-on (default: 15 30 60 120)")
    ap.add_argument("--small", action="store_true", help="a short-chirp rig (1024 samples): seconds, for the tests")
    a = ap.parse_args(argv)
    if any(not m > 0 for m in a.minutes):
        ap.error("--minutes must all be > 0")
    rig = Rig.load(a.rig)
    if a.small:
        rig = dataclasses.replace(rig, n_chirp=1024)
    sc = Scenario.load(a.scenario)
    print(f"thermal budget: scenario {sc.name}, rig {rig.name} ({rig.n_chirp}-sample chirps), material {sc.material}, "
          f"warm-up {sc.temperature}", file=sys.stderr)
    rows = budget(Simulator(sc.replace(sessions=1), rig), list(a.minutes))
    out = ["| minutes after power-on | TX bond warming | RX bond warming | received spectrum change (median over the band) "
           "| of it: bonds | wall stretch | wall non-uniform (Born) |",
           "|---|---|---|---|---|---|---|"]
    for r in rows:
        out.append(f"| {r['minutes']:g} | +{r['tx_k']:.1f} K | +{r['rx_k']:.1f} K | {r['total']:.1f} dB | {r['bonds']:.1f} dB "
                   f"| {_num(r['stretch'])} dB | {_num(r['born'])} dB |")
    print("\n".join(out))
    return 0


if __name__ == "__main__":
    sys.exit(main())
