import numpy as np
import pytest

from sonicskin.calibration import ScoreCalibrator, TouchDetector


def test_calibration_cancels_an_injected_drift(rng):
    n, K = 6000, 4
    t = np.arange(n)
    drift = np.outer(t / n, [3.0, -2.0, 1.0, 0.5])  # slow temperature drift of the scores
    quiet = np.ones(n, bool)
    for start in rng.choice(np.arange(100, n - 40, 40), 30, replace=False):
        quiet[start : start + 30] = False  # 30 presses of 3 s
    scores = drift + rng.normal(0, 0.05, (n, K))
    scores[~quiet, 1] += 5  # touches at location 1
    cal = ScoreCalibrator(beta_chirps=28, alpha_chirps=500).run(scores, quiet)
    # Quiet chirps stay near zero despite a drift of up to 3: residual <= drift over one alpha.
    assert np.abs(cal[quiet]).max() < 3.0 * 600 / n + 0.3
    assert np.abs(scores[quiet] - scores[quiet][:28].mean(0)).max() > 2.5  # no refresh: drift stays
    # Touches still stand out.
    assert np.all(cal[~quiet, 1] > 4)
    never = ScoreCalibrator(beta_chirps=28, alpha_chirps=None).run(scores, quiet)
    assert np.abs(never[quiet][-100:]).max() > 2.0


def test_reference_schedule_waits_for_quiet(rng):
    quiet = np.ones(100, bool)
    quiet[50:70] = False  # a touch when the refresh falls due
    refs = ScoreCalibrator(beta_chirps=5, alpha_chirps=48).reference_times(quiet)
    assert [list(r[1]) for r in refs[:2]] == [[0, 1, 2, 3, 4], [70, 71, 72, 73, 74]]
    assert refs[1][0] == 75  # valid after its last chirp
    # With a clock, alpha counts seconds of stream time across gaps.
    cal = ScoreCalibrator.from_seconds(beta_s=1.0, alpha_s=60.0, chirps_per_s=10.0)
    assert (cal.beta_chirps, cal.alpha_chirps) == (10, 600)
    times = np.r_[np.arange(20) / 10, 1000 + np.arange(20) / 10]
    refs = cal.reference_times(np.ones(40, bool), times)
    assert [int(r[1][0]) for r in refs] == [0, 20]
    with pytest.raises(ValueError, match="fewer than beta=28 no-touch chirps"):
        ScoreCalibrator().run(np.zeros((10, 3)), np.ones(10, bool))


def test_detector_threshold_separates_touch_from_quiet(rng):
    touch = rng.normal(3, 0.5, (500, 5))
    quiet = rng.normal(0, 0.5, (500, 5))
    d = TouchDetector().fit(touch, quiet)
    assert 0.5 < d.threshold_ < 3.0
    assert d.false_touch_rate_ < 0.05 and d.missed_touch_rate_ < 0.05
    assert d.predict(np.array([[5.0, 0, 0, 0, 0], [-1, -1, -1, -1, -1]])).tolist() == [True, False]
    with pytest.raises(ValueError, match="need both touch and no-touch"):
        TouchDetector().fit(np.empty((0, 5)), quiet)
