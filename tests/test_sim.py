"""Physical sanity of the simulated rig."""

import numpy as np
import pytest

from sonicskin.dsp import log_magnitude_db
from sonicskin.sim import MATERIALS, ChannelModel, Geometry, Scenario, Simulator, build_timeline
from sonicskin.sim.channel import mindlin_omega
from sonicskin.sim.noise import NoiseConfig, motion_noise_spectrum
from sonicskin.sim.scenario import Timeline

CFRP = MATERIALS["cfrp"]


@pytest.fixture(scope="module")
def chan(rig):
    return ChannelModel(rig, CFRP, Geometry(), seed=0)


@pytest.fixture(scope="module")
def sim(rig):
    return Simulator(Scenario(), rig)


def _event(sim, loc_xy_cm, forces, dT=0.0, subject=0, moving=0.0):
    n = len(forces)
    z = np.zeros(n)
    return Timeline(session=z.astype(int), chirp=np.arange(n), time_s=z, segment=np.full(n, 2), event=np.zeros(n, int),
                    location=np.zeros(n, int), x_cm=np.full(n, loc_xy_cm[0]), y_cm=np.full(n, loc_xy_cm[1]),
                    force_n=np.asarray(forces, float), moving=np.full(n, moving), temperature_c=np.full(n, 23.0 + dT),
                    subject=np.full(n, subject))


def test_wavelengths_match_design_numbers():
    # DESIGN.md: CFRP 2 mm wall 3.2 / 1.9 / 1.4 cm at 20 / 50 / 80 kHz (Mindlin), Al 2 mm 3.1 / 1.9 / 1.5.
    lam = 2 * np.pi / CFRP.wavenumber(np.array([20e3, 50e3, 80e3])) * 100
    np.testing.assert_allclose(lam, [3.2, 1.9, 1.45], rtol=0.06)
    lam_al = 2 * np.pi / MATERIALS["aluminium"].wavenumber(np.array([20e3, 50e3, 80e3])) * 100
    np.testing.assert_allclose(lam_al, [3.1, 1.9, 1.5], rtol=0.08)
    # Mindlin is slower than Kirchhoff at 80 kHz, and agrees at low frequency.
    k = CFRP.wavenumber(80e3)
    w_kirch = k ** 2 * np.sqrt(CFRP.bending_stiffness / CFRP.mass_per_area)
    assert mindlin_omega(k, CFRP) < 0.95 * w_kirch
    k1 = CFRP.wavenumber(1e3)
    assert mindlin_omega(k1, CFRP) == pytest.approx(k1 ** 2 * np.sqrt(CFRP.bending_stiffness / CFRP.mass_per_area), rel=3e-3)


def test_modal_density_matches_plate_asymptote(chan):
    # Kirchhoff plate: n(f) = A / 2 * sqrt(rho h / D) modes per Hz; Mindlin adds modes at high f.
    A = chan.geometry.width_m * chan.geometry.length_m
    n_kirch = A / 2 * np.sqrt(CFRP.mass_per_area / CFRP.bending_stiffness)
    ratio = chan.modal_density_per_hz() / n_kirch
    assert 1.0 < ratio < 1.4


def test_measured_wavenumber_of_the_field(rig, chan):
    # Sample the wall's response to the TX at 50 kHz on a grid around the tube; its 2-D spatial
    # spectrum concentrates on the ring |k| = k(50 kHz) of the dispersion relation.
    nx, ny = 64, 96
    W, L = chan.geometry.width_m, chan.geometry.length_m
    xs, ys = np.arange(nx) * W / nx, 0.05 + np.arange(ny) * (L - 0.1) / ny
    pts = np.stack(np.meshgrid(xs, ys, indexing="ij"), -1).reshape(-1, 2)
    b = int(np.argmin(np.abs(chan.f_hz - 50e3)))
    M = chan._Mr[:, b] + 1j * chan._Mi[:, b]
    field = (chan.mode_shapes(pts) @ (chan.phi_tx * M)).reshape(nx, ny) * np.hanning(ny)[None, :]
    P = np.abs(np.fft.fft2(field)) ** 2
    kx = 2 * np.pi * np.fft.fftfreq(nx, W / nx)
    ky = 2 * np.pi * np.fft.fftfreq(ny, (L - 0.1) / ny)
    kr = np.hypot(*np.meshgrid(kx, ky, indexing="ij"))
    k_meas = np.sum(kr * P) / np.sum(P)
    assert k_meas == pytest.approx(CFRP.wavenumber(50e3), rel=0.15)


def test_reciprocity(rig):
    a, b = np.array([0.03, 0.05]), np.array([0.11, 0.2])
    c = ChannelModel(rig, CFRP, Geometry(), seed=1)
    np.testing.assert_allclose(c.transfer_between(a, b), c.transfer_between(b, a), rtol=1e-5)
    fwd = ChannelModel(rig, CFRP, Geometry(), tx_m=(0.0, 0.025), rx_m=(0.059, 0.225), seed=1)
    rev = ChannelModel(rig, CFRP, Geometry(), tx_m=(0.059, 0.225), rx_m=(0.0, 0.025), seed=1)
    np.testing.assert_allclose(fwd.G_rs, rev.G_rs, rtol=1e-4, atol=1e-6 * np.abs(fwd.G_rs).max())
    # The touched response too: a finger is a passive, reciprocal load.
    G1, G2 = fwd.contact_greens(np.array([[0.05, 0.12]]), np.array([5e-3])), rev.contact_greens(np.array([[0.05, 0.12]]), np.array([5e-3]))
    K = 1e4j
    h1 = fwd.G_rs - G1[0, 0, 0] * K * G1[0, 0, 1] / (1 + K * G1[0, 0, 2])
    h2 = rev.G_rs - G2[0, 0, 0] * K * G2[0, 0, 1] / (1 + K * G2[0, 0, 2])
    np.testing.assert_allclose(h1, h2, rtol=1e-3, atol=1e-5 * np.abs(h1).max())


def test_harder_press_changes_the_spectrum_more(sim):
    H = sim.channel_response(_event(sim, (8.0, 12.5), [0.5, 2.0, 8.0]))
    H0 = sim.untouched(np.zeros(1))[0]
    dev = np.mean(np.abs(20 * np.log10(np.abs(H) / np.abs(H0))), axis=1)
    assert dev[0] < dev[1] < dev[2]
    assert dev[0] > 0.1  # even a light touch is a clear change (dB)


def test_nearby_locations_differ_and_repeated_chirps_agree(rig, sim):
    ev_a = _event(sim, (8.0, 12.5), [3.0] * 4)
    ev_b = _event(sim, (9.2, 12.5), [3.0] * 4)
    Xa = log_magnitude_db(sim.render(ev_a), rig)
    Xb = log_magnitude_db(sim.render(ev_b, rng=np.random.default_rng(9)), rig)
    band = rig.allowed_mask
    within = np.median(np.abs(Xa[0] - Xa[1])[band])
    between = np.median(np.abs(Xa[0] - Xb[0])[band])
    assert between > 5 * within


def test_pwm_lines_sit_where_configured(rig):
    cfg = NoiseConfig(mech_rms=0.0, gear_rms=0.0, impact_rate_per_chirp=0.0, pwm_jitter_hz=0.0)
    Y = motion_noise_spectrum(np.random.default_rng(0), np.ones(3), cfg, n_fft=rig.n_chirp, fs_hz=rig.fs_hz)
    f = rig.freqs_hz
    strongest = f[np.argsort(np.abs(Y[0]))[-3 * 9:]]
    centres = np.array([30e3, 60e3, 90e3])
    nearest = np.min(np.abs(strongest[:, None] - centres[None, :]), axis=1)
    assert np.all(nearest <= cfg.pwm_sidebands * cfg.pwm_f0_hz + 2 * rig.fs_hz / rig.n_chirp)
    # The three carriers themselves are present.
    for fc in centres:
        k = int(round(fc / (rig.fs_hz / rig.n_chirp)))
        assert np.abs(Y[0, k - 1:k + 2]).max() > 100 * np.median(np.abs(Y[0]))


def test_warming_moves_resonances_down_by_kappa(sim):
    dT = 5.0
    H0, HT = np.abs(sim.untouched(np.array([0.0, dT])))
    f = sim.channel.f_hz
    sel = (f > 45e3) & (f < 55e3)
    a, b = np.log(H0[sel]), np.log(HT[sel])
    lags = np.arange(-30, 31)
    cc = [np.corrcoef(a[30:-30], np.roll(b, -lag)[30:-30])[0, 1] for lag in lags]
    shift_hz = lags[int(np.argmax(cc))] * sim.channel.df_hz
    expected = 50e3 * sim.material.kappa_per_k * dT  # about -88 Hz
    assert shift_hz == pytest.approx(expected, abs=2 * sim.channel.df_hz)


def test_same_seed_same_data(rig):
    sc = Scenario(sessions=1, layout={"kind": "grid", "nx": 2, "ny": 1, "spacing_cm": 1.2, "x0_cm": 8, "y0_cm": 12},
                  touch_s=0.5, calibration_s=0.3, gap_s=0.1, motion={"enabled": True}, moving_s=0.3)
    tl = build_timeline(sc, rig)
    a = Simulator(sc, rig).render(tl)
    b = Simulator(sc, rig).render(tl)
    np.testing.assert_array_equal(a, b)
    c = Simulator(sc.replace(seed=1), rig).render(build_timeline(sc.replace(seed=1), rig))
    assert not np.array_equal(a, c)
    assert np.abs(a).max() < 1.0 and a.dtype == np.float32
    # 24-bit quantisation: every sample sits on the grid.
    q = a.astype(np.float64) * (2 ** 23 - 1)
    assert np.allclose(q, np.round(q), atol=2e-3)
