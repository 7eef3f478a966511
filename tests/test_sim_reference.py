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


def test_batched_woodbury_solve_equals_lapack(rig):
    # The finger's P x P systems are solved by elimination over whole arrays, without pivoting:
    # it must agree with LAPACK (partial pivoting, complex128) on light and firm presses, on the
    # low-loss aluminium plate as on the CFRP tube.
    from sonicskin.sim import Scenario, Simulator
    from sonicskin.sim.simulator import _woodbury

    for name in ("moving", "plate-aluminium"):
        sim = Simulator(Scenario.load(name), rig)
        who = sim.subjects[3]
        radii = who.radius_m(np.array([0.3, 3.0, 12.0]))
        pts = [sim._patch_points(np.array([0.08, 0.12]), r, 0.4) for r in radii]
        W = np.concatenate([sim.channel.patch_weights(p, r / 2) for r, p in zip(radii, pts)])
        Gp = sim.channel._project(W).reshape(3, -1, sim.channel.f_hz.size)
        occl = np.array([0.5, 1.0])
        K = np.stack([who.dynamic_stiffness(np.full(2, who.force_at_radius(r)), sim.channel.f_hz, occl) for r in radii]) / 4
        got = _woodbury(Gp, K, 4)
        P, iu, ju = 4, *np.triu_indices(4)
        for r in range(3):
            G_pp = np.empty((P, P, Gp.shape[2]), complex)
            G_pp[iu, ju] = Gp[r, 2 * P:]
            G_pp[ju, iu] = Gp[r, 2 * P:]
            for o in range(2):
                k = K[r, o].astype(complex)
                A = np.eye(P)[None] + k[:, None, None] * np.moveaxis(G_pp, -1, 0)
                y = np.linalg.solve(A, (k * Gp[r, P:2 * P]).T[..., None])[..., 0]
                want = -np.sum(Gp[r, :P].T * y, axis=1)
                err = np.abs(got[r, o] - want) / np.abs(want).max()
                assert err.max() < 1e-4, (name, r, o, err.max())
                assert np.abs(want).max() > 1e-3 * np.abs(sim.channel.G_rs).max()  # a real change of H
