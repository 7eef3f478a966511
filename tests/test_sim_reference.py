"""The simulator's output is pinned to a stored reference (tests/fixtures/sim_reference.npz, written by
tests/make_sim_reference.py before the speed work): faster code must render the same audio, up to
float32 rounding (a few 24-bit codes), so the physics cannot change silently."""

import numpy as np
from make_sim_reference import FIXTURE, cases


def test_simulator_output_matches_the_stored_reference():
    ref = np.load(FIXTURE)
    for name, sim, tl, rows in cases():
        np.testing.assert_array_equal(ref[f"{name}_rows"], rows)
        q = np.round(sim.render(tl)[rows].astype(np.float64) * (2 ** 23 - 1))
        r = ref[f"{name}_q"].astype(np.float64)
        rms = np.sqrt(np.mean(r ** 2))
        assert rms > 1e4, name  # a real signal, not silence (full scale: 8.4e6 codes)
        diff = np.abs(q - r)
        # float32 rounding: a few codes of 8.4e6 at most, and on average well under one code.
        assert diff.max() <= 8, (name, diff.max())
        assert diff.mean() <= 0.5, (name, diff.mean())
