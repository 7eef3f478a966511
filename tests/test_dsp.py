import numpy as np
import pytest
import scipy.signal

from sonicskin import dsp
from sonicskin.dsp import FrameError


def test_chirp_sweeps_the_configured_band(rig):
    s = dsp.rig_chirp(rig)
    assert s.shape == (20480,) and np.max(np.abs(s)) == pytest.approx(rig.amplitude, rel=1e-3)
    phase = np.unwrap(np.angle(scipy.signal.hilbert(s)))
    f_inst = np.diff(phase) * rig.fs_hz / (2 * np.pi)
    mid = slice(200, -200)  # away from the Hilbert transform's edge effects
    t = (np.arange(s.size - 1) + 0.5) / rig.fs_hz
    expected = rig.f_lo_hz + (rig.f_hi_hz - rig.f_lo_hz) * t / rig.period_s
    assert np.max(np.abs(f_inst[mid] - expected[mid])) < 300  # Hz
    # Eq. 1: s(t) = sin(a t^2 + Omega_1 t + phi) starts at sin(phi) = 0.
    assert s[0] == pytest.approx(0.0, abs=1e-9)


@pytest.mark.parametrize("seed", range(5))
def test_framing_recovers_random_offsets_exactly(rig, seed):
    rng = np.random.default_rng(seed)
    s = dsp.rig_chirp(rig)
    L = rig.n_chirp
    offset = int(rng.integers(0, L))
    n = 4
    train = np.tile(s, n + 1)
    stream = train[(L - offset) % L : (L - offset) % L + n * L + 1234]  # starts mid-chirp
    stream = stream + rng.normal(0, 0.05, stream.size)  # noise at -20 dB re. the chirp
    frames, off = dsp.frame_stream(stream, s)
    assert off == offset % L
    assert frames.shape[1] == L
    assert frames.shape[0] == (stream.size - off) // L  # partial chirps dropped
    np.testing.assert_allclose(frames[0], s + (stream[off:off + L] - s), atol=1e-5)


def test_identity_channel_gives_0_db(rig):
    frames = np.tile(dsp.rig_chirp(rig), (3, 1)).astype(np.float32)
    X = dsp.log_magnitude_db(frames, rig)
    assert X.shape == (3, rig.n_band) and X.dtype == np.float32
    assert np.max(np.abs(X)) < 0.05
    # A channel of gain 0.5 is -6.02 dB in every band bin.
    assert np.allclose(dsp.log_magnitude_db(frames * 0.5, rig), -6.0206, atol=0.05)


def test_bad_frames_are_named(rig):
    good = np.tile(dsp.rig_chirp(rig), (2, 1)).astype(np.float32)
    with pytest.raises(FrameError, match="frame length 1000 does not match the rig's chirp of 20480"):
        dsp.check_frames(good[:, :1000], rig)
    bad = good.copy(); bad[1, 5] = np.nan
    with pytest.raises(FrameError, match="frame 1 contains NaN"):
        dsp.check_frames(bad, rig)
    with pytest.raises(FrameError, match="silent"):
        dsp.check_frames(np.zeros_like(good), rig)
    with pytest.raises(FrameError, match="clipped"):
        dsp.check_frames(np.clip(good * 4, -1, 1), rig)
    with pytest.raises(FrameError, match="floating point"):
        dsp.check_frames((good * 1000).astype(np.int16), rig)
    with pytest.raises(FrameError, match="fewer than one chirp period"):
        dsp.frame_stream(good[0, :100], dsp.rig_chirp(rig))
    assert list(dsp.frame_faults(np.stack([good[0], bad[1], np.zeros(20480), np.ones(20480)]))) == [0, 1, 2, 3]
