"""Write tests/fixtures/sim_reference.npz: the simulator's output on two small cases, pinned by
tests/test_sim_reference.py so that speed work cannot change the physics silently.

Run only when the physics is changed on purpose: ``python tests/make_sim_reference.py``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

FIXTURE = Path(__file__).parent / "fixtures" / "sim_reference.npz"


def cases():
    """(name, simulator, timeline, rows to keep): every part of the physics on a few chirps."""
    from cli_helpers import SMALL_RIG, TINY_SCENARIO

    from sonicskin.rig import Rig
    from sonicskin.sim import Scenario, Simulator, build_timeline

    # The paper's rig on the moving CFRP tube: warm-up gradient, motion ripple and noise, two presses.
    rig = Rig.load("jaco")
    sc = Scenario.load("moving").replace(
        sessions=1, train_repeats=None, layout={"kind": "grid", "nx": 2, "ny": 1, "spacing_cm": 1.2, "x0_cm": 8, "y0_cm": 12},
        touch_s=0.6, calibration_s=0.3, gap_s=0.1, moving_s=0.3)
    tl = build_timeline(sc, rig)
    touch = np.flatnonzero(tl.force_n > 0)
    rows = np.array([0, int(np.flatnonzero(tl.segment == 1)[0]), int(touch[2]), int(touch[-2])])
    yield "jaco", Simulator(sc, rig), tl, rows
    # The small CLI rig on the tiny ABS plate, with motion switched on: every 30th chirp of a session.
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        (Path(d) / "small.yaml").write_text(SMALL_RIG)
        (Path(d) / "tiny.yaml").write_text(TINY_SCENARIO)
        srig = Rig.load(Path(d) / "small.yaml")
        ssc = Scenario.load(Path(d) / "tiny.yaml").replace(sessions=1, motion={"enabled": True, "perturbation": 0.03},
                                                             moving_s=0.5, start_s=3600.0)
    stl = build_timeline(ssc, srig)
    yield "small", Simulator(ssc, srig), stl, np.arange(0, len(stl), 30)


def main() -> None:
    out = {}
    for name, sim, tl, rows in cases():
        x = sim.render(tl)
        out[f"{name}_rows"] = rows
        out[f"{name}_q"] = np.round(x[rows].astype(np.float64) * (2 ** 23 - 1)).astype(np.int32)  # 24-bit codes
    FIXTURE.parent.mkdir(exist_ok=True)
    np.savez_compressed(FIXTURE, **out)
    print(f"wrote {FIXTURE} ({FIXTURE.stat().st_size / 1e3:.0f} kB)")


if __name__ == "__main__":
    import sys

    sys.path.insert(0, str(Path(__file__).parent))
    main()
