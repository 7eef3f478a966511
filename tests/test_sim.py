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


# -- temperature: hot-melt bond, non-uniform warm-up -------------------------------------------------

def test_hot_melt_bond_softens_with_the_cited_slope_and_its_resonance_moves_down():
    from sonicskin.sim.thermal import HotMeltBond

    bond = HotMeltBond()
    T = np.arange(20.0, 31.0)
    E = bond.modulus_ratio(T)
    assert np.all(np.diff(E) < 0) and E[T == 23.0] == pytest.approx(1.0)
    np.testing.assert_allclose(np.diff(np.log10(E)), -0.02)  # d log10 E' / dT of an EVA hot melt above its Tg
    assert np.all(np.diff(bond.loss_tangent(T)) > 0)  # loss tangent rises towards the transition
    # The mounted resonance is where |transmissibility| peaks: it follows sqrt(E') down (-2.3 %/K).
    f = np.linspace(10e3, 60e3, 5001)
    peaks = f[np.argmax(np.abs(bond.response(f, np.array([23.0, 28.0]))), axis=1)]
    assert peaks[1] < peaks[0]
    assert peaks[1] / peaks[0] == pytest.approx(np.sqrt(10 ** (-0.02 * 5)), rel=0.03)


def test_uniform_stiffness_born_term_matches_the_exact_frequency_shift(rig, chan):
    # Order 0 (uniform) profile: the Born term must be the derivative of the modal sum when every
    # w_n^2 scales by (1 + eps) -- a check of the mode normalisation and the overlap integrals.
    eps = 1e-4
    M = chan._Mr.astype(np.float64) + 1j * chan._Mi.astype(np.float64)
    w = 2 * np.pi * chan.f_hz
    M2 = 1 / (chan.wn2[:, None] * (1 + eps) * (1 + 1j * CFRP.eta) - w[None, :] ** 2)
    wrs = chan.phi_tx * chan.phi_rx
    fd = (wrs @ M2 - wrs @ M) / eps
    B0 = chan.gradient_greens(order=0)
    band = (chan.f_hz > 20e3) & (chan.f_hz < 80e3)
    assert np.linalg.norm(B0[band] - fd[band]) < 0.02 * np.linalg.norm(fd[band])


def test_non_uniform_warming_changes_the_response_beyond_a_uniform_stretch(rig):
    # Odd (linear) gradient: cancels exactly at first order when TX and RX are mirror images along
    # the link (the default tube: y = 2.5 and 22.5 of 25 cm); with the RX moved off the mirror
    # position it does act, and the even (ends vs middle) profile acts in both.
    sym = ChannelModel(rig, CFRP, Geometry(), seed=0)
    asym = ChannelModel(rig, CFRP, Geometry(), rx_m=(0.059, 0.18), seed=0)
    band = (sym.f_hz > 20e3) & (sym.f_hz < 80e3)
    rel = lambda c, k: np.median(np.abs(c.gradient_greens(order=k)[band])) / np.median(np.abs(c.G_rs[band]))  # noqa: E731
    assert rel(sym, 1) < 1e-6
    assert rel(asym, 1) > 1e-3 and rel(sym, 2) > 1e-3 and rel(asym, 2) > 1e-3


def test_warm_up_reaches_the_motor_end_first(rig):
    sc = Scenario.load("drift-2h")
    sim = Simulator(sc, rig)
    t = np.array([0.0, 600.0, 3600.0, 7200.0])
    n = t.size
    z = np.zeros(n)
    tl = Timeline(session=z.astype(int), chirp=np.arange(n), time_s=t, segment=z.astype(int), event=-np.ones(n, int),
                  location=-np.ones(n, int), x_cm=z, y_cm=z, force_n=z, moving=z, temperature_c=sc.temperature_c(t),
                  subject=z.astype(int))
    temps = sim.temperatures(tl)
    assert temps["tx_c"][0] == temps["rx_c"][0] == pytest.approx(23.0)
    assert np.all(temps["tx_c"][1:] > temps["rx_c"][1:])  # TX sits at the motor end
    assert np.all(np.diff(temps["tx_c"]) > 0) and np.all(temps["dT_grad"][1:, 0] > 0)
    # The label is the link's middle; 5.6 K final rise of the scenario, 90 min time constant there.
    assert tl.temperature_c[-1] - 23.0 == pytest.approx(5.6 * (1 - np.exp(-7200 / 5400)))


# -- fingers -----------------------------------------------------------------------------------------

def test_finger_contact_grows_with_force_and_hold_time_as_cited():
    from sonicskin.sim.finger import make_subjects

    f = np.array([50e3])
    for who in make_subjects():
        F = np.array([1.0, 2.0, 5.0, 10.0])
        a = who.radius_m(F)
        assert np.all(np.diff(a) > 0) and np.all(np.diff(np.log(a)) < np.diff(np.log(F)) / 2)  # sub-linear, Hertz-like
        K = who.dynamic_stiffness(F, f)[:, 0]
        w = 2 * np.pi * f[0]
        c = K.imag / w
        # Skin damping ~ real contact area ~ F^q, q in 0.6-1: keeps growing where the gross area saturates.
        q = np.diff(np.log(c)) / np.diff(np.log(F))
        np.testing.assert_allclose(q, who.damping_exp, rtol=1e-3)
        assert 0.6 <= who.damping_exp <= 1.0
        # Pad stiffness linear in force (exponential force-displacement law): k(10 N) / k(1 N) = 8.2 / 1.
        k = who.dynamic_stiffness(F, np.array([0.0]))[:, 0].real
        assert k[3] / k[0] == pytest.approx(8.2)
        # Real contact grows while held: g(0) = r0, saturates within ~20 s.
        g = who.occlusion(np.array([0.0, 3.0, 20.0]))
        assert g[0] == pytest.approx(who.occlusion_r0) and g[0] < g[1] < g[2] and g[2] > 0.95


def test_one_shot_session_has_several_presses_per_location(rig):
    sc = Scenario(sessions=2, train_repeats=3, layout={"kind": "grid", "nx": 2, "ny": 1, "spacing_cm": 1.2, "x0_cm": 8,
                                                        "y0_cm": 12}, touch_s=0.5, calibration_s=0.3, gap_s=0.1)
    tl = build_timeline(sc, rig)
    presses = lambda s: len(np.unique(tl.event[(tl.session == s) & (tl.event >= 0)]))  # noqa: E731
    assert presses(0) == 6 and presses(1) == 2
    with pytest.raises(ValueError, match="train_repeats"):
        Scenario.from_dict({"train_repeats": 0})


def test_sessions_never_overlap_in_time():
    """drift-2h tests every 300 s, but its one-shot session (three passes over 31 markers) lasts 330 s: the next session
    starts when it ends, not during it, so the recording from power-on is one stream in time order (reproduce's Fig. 12
    replays it so); sessions shorter than the interval keep their schedule."""
    from sonicskin.rig import Rig
    from sonicskin.sim import Scenario, build_timeline

    rig = Rig.load("jaco")
    tl = build_timeline(Scenario.load("drift-2h").replace(sessions=3), rig)
    starts = [tl.time_s[tl.session == k][0] for k in range(3)]
    end0 = tl.time_s[tl.session == 0][-1] + rig.period_s
    assert end0 > 300.0 and starts[1] == pytest.approx(end0) and starts[2] == 600.0
    assert np.all(np.diff(tl.time_s) > 0)
    tl = build_timeline(Scenario.load("moving"), rig)  # 3 sessions shorter than 600 s: on the hour plus 10 min steps
    assert [tl.time_s[tl.session == k][0] for k in range(3)] == [3600.0, 4200.0, 4800.0]
