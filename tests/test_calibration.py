import numpy as np
import pytest

from sonicskin.calibration import OnlineReference, TouchDetector
from sonicskin.features import relative_features


def test_labelled_reference_cancels_an_injected_drift(rng):
    """Training sessions: Alg. 2 on the features from the known no-touch chirps (relative_features)."""
    n, K = 6000, 4
    t = np.arange(n)
    drift = np.outer(t / n, [3.0, -2.0, 1.0, 0.5])  # slow temperature drift of the features
    quiet = np.ones(n, bool)
    for start in rng.choice(np.arange(100, n - 40, 40), 30, replace=False):
        quiet[start : start + 30] = False  # 30 presses of 3 s
    X = drift + rng.normal(0, 0.05, (n, K))
    X[~quiet, 1] += 5  # touches at location 1
    session, clock = np.zeros(n, int), t / 10.0
    cal = relative_features(X, quiet, session, clock, OnlineReference(28, 500, 10.0))
    # Quiet chirps stay near zero despite a drift of up to 3: residual <= drift over one alpha.
    assert np.abs(cal[quiet]).max() < 3.0 * 600 / n + 0.3
    assert np.abs(X[quiet] - X[quiet][:28].mean(0)).max() > 2.5  # no refresh: drift stays
    assert np.all(cal[~quiet, 1] > 4)  # touches still stand out
    never = relative_features(X, quiet, session, clock, OnlineReference(28, 500, 10.0), online=False)
    assert np.abs(never[quiet][-100:]).max() > 2.0
    with pytest.raises(ValueError, match="session 0: fewer than 28 consecutive hands-off chirps"):
        relative_features(X[:20], quiet[:20], session[:20], clock[:20], OnlineReference(28, 500, 10.0))


def test_reference_clock_counts_stream_time_across_gaps(rng):
    ref = OnlineReference.from_seconds(beta_s=1.0, alpha_s=60.0, chirps_per_s=10.0)
    assert (ref.beta, ref.alpha) == (10, 600)
    times = np.r_[np.arange(20) / 10, 1000 + np.arange(20) / 10]  # a recording with a 1000 s gap
    x = (np.r_[np.zeros(20), np.full(20, 5.0)] + rng.normal(0, 0.1, 40))[:, None]  # the wall moved while off
    done = [i for i in range(40) if ref.step(x[i], times[i], False if ref.ready else None)]
    assert done == [9, 29]  # boot on chirps 0-9; the 1000 s gap (> alpha) re-boots on chirps 20-29
    assert ref.reboots == 1
    # A disturbed first boot (chirps 2-9 lost) does not make a clean re-boot read disturbed or refresh early.
    d = OnlineReference.from_seconds(beta_s=1.0, alpha_s=60.0, chirps_per_s=10.0)
    keep = [0, 1, 2, 12] + list(range(20, 40))
    assert [i for i in keep if d.step(x[i], times[i], False if d.ready else None)] == [12, 29]
    assert d.boot_disturbed is False and d.reboots == 1
    assert not any(d.step(x[i], 1002.0 + i / 10, False) for i in range(10))  # no early refresh after the re-boot
    np.testing.assert_allclose(ref.features, x[20:30].mean(axis=0), rtol=1e-6)
    with pytest.raises(RuntimeError, match="no reference yet"):
        OnlineReference().inputs(np.zeros(3))


def test_detector_threshold_separates_touch_from_quiet(rng):
    touch = rng.normal(3, 0.5, (500, 5))
    quiet = rng.normal(0, 0.5, (500, 5))
    d = TouchDetector().fit(touch, quiet)
    assert 0.5 < d.threshold_ < 3.0
    assert d.false_touch_rate_ < 0.05 and d.missed_touch_rate_ < 0.05
    assert d.predict(np.array([[5.0, 0, 0, 0, 0], [-1, -1, -1, -1, -1]])).tolist() == [True, False]
    with pytest.raises(ValueError, match="need both touch and no-touch"):
        TouchDetector().fit(np.empty((0, 5)), quiet)


def test_online_reference_boot_and_refresh_by_detection(rng):
    ref = OnlineReference(beta_chirps=5, alpha_chirps=20, chirps_per_s=10.0, score_fn=lambda x: x.sum(axis=1, keepdims=True))
    X = rng.normal(0, 0.01, (80, 3)).astype(np.float32) + np.arange(80)[:, None]  # a drifting channel
    touch = np.zeros(80, bool)
    touch[22:40] = True  # a press when the refresh falls due (20 chirps after the boot's last chirp, 4)
    t = np.arange(80) / 10.0
    done = []
    for i in range(80):
        was = ref.ready
        if ref.step(X[i], t[i], bool(touch[i]) if was else None):
            done.append(i)
    # Boot: chirps 0-4, taken as hands-off whatever happens; refresh: 5 no-touch chirps after the press.
    assert done == [4, 44, 68]  # due 20 chirps after 44: chirps 64-68
    np.testing.assert_allclose(ref.features, X[64:69].mean(0), rtol=1e-6)
    np.testing.assert_allclose(ref.scores, [0.0], atol=1e-4)  # scores of the reference's own relative inputs
    # Known labels during boot (a labelled training stream): the boot waits for 5 quiet chirps.
    lab = OnlineReference(beta_chirps=5, alpha_chirps=None)
    flags = np.r_[np.ones(3, bool), np.zeros(10, bool)]
    assert [i for i in range(13) if lab.step(X[i], t[i], bool(flags[i]))] == [7]
    assert not any(lab.step(X[i], t[i], False) for i in range(13, 80))  # alpha None: never refreshes


def test_online_reference_replay_equals_chirp_by_chirp(rng):
    from types import SimpleNamespace

    X = rng.normal(0, 1, (400, 4)).astype(np.float32) + np.linspace(0, 3, 400)[:, None]
    t = np.arange(400) / 10.0

    def predict(inputs):  # a detector that depends on the reference
        return SimpleNamespace(touch=np.abs(inputs).mean(axis=1) > 1.1, inputs=inputs)

    a = OnlineReference(beta_chirps=6, alpha_chirps=30, chirps_per_s=10.0)
    step_out = []
    for i in range(400):
        if not a.ready:
            a.step(X[i], t[i])
            continue
        p = predict(a.inputs(X[i][None]))
        step_out.append(p.inputs[0])
        a.step(X[i], t[i], bool(p.touch[0]))
    b = OnlineReference(beta_chirps=6, alpha_chirps=30, chirps_per_s=10.0)
    blocks = list(b.replay(X, t, predict))
    assert blocks[0][:2] == (0, 6) and blocks[0][2] is None  # the boot: no prediction
    got = np.concatenate([out.inputs[: hi - lo] for lo, hi, out in blocks[1:]])
    assert blocks[1][0] == 6 and blocks[-1][1] == 400 and b.refreshes == a.refreshes
    np.testing.assert_array_equal(got, np.stack(step_out))
    assert a.refreshes >= 4  # boot + refreshes decided on the replayed detections


def test_a_pause_longer_than_alpha_reboots_the_reference_even_when_every_chirp_reads_touched():
    """Days off (the wall warmed by kelvins): the old reference calls every chirp touched, so Alg. 2 would never
    refresh; the first beta chirps after the pause are a boot (hands off by protocol), with no prediction, in the
    chirp-by-chirp path and the vectorised replay alike."""
    from types import SimpleNamespace

    beta, alpha, cps = 5, 50, 10.0
    t = np.r_[np.arange(100) / cps, 3600 + np.arange(100) / cps]  # an hour off after 10 s
    X = np.r_[np.zeros((100, 2)), np.full((100, 2), 4.0)].astype(np.float32)  # the channel moved while off

    def predict(inputs):  # touched wherever the input is far from the reference
        return SimpleNamespace(touch=np.abs(inputs).max(axis=1) > 1.0, inputs=inputs)

    a = OnlineReference(beta, alpha, cps)
    touched, booting = [], []
    for i in range(200):
        booting.append(a.booting_at(t[i]))
        if booting[-1]:
            a.step(X[i], t[i])
            continue
        p = predict(a.inputs(X[i][None]))
        touched.append(bool(p.touch[0]))
        a.step(X[i], t[i], touched[-1])
    assert np.flatnonzero(booting).tolist() == [0, 1, 2, 3, 4, 100, 101, 102, 103, 104]
    assert a.reboots == 1 and not any(touched)  # the old reference would call all 100 touched
    np.testing.assert_allclose(a.features, [4.0, 4.0])
    b = OnlineReference(beta, alpha, cps)
    blocks = list(b.replay(X, t, predict))
    assert [(lo, hi) for lo, hi, out in blocks if out is None] == [(0, 5), (100, 105)]
    got = np.concatenate([out.touch[: hi - lo] for lo, hi, out in blocks if out is not None])
    assert got.tolist() == touched and b.reboots == 1 and b.refreshes == a.refreshes
    # alpha None ("never refresh", Fig. 12's baseline): a pause changes nothing
    c = OnlineReference(beta, None, cps)
    blocks = list(c.replay(X, t, predict))
    assert [(lo, hi) for lo, hi, out in blocks if out is None] == [(0, 5)] and c.reboots == 0
    assert np.concatenate([out.touch[: hi - lo] for lo, hi, out in blocks if out is not None])[95:].all()


def test_a_labelled_stream_reboots_on_its_known_no_touch_chirps():
    """Training sessions feed labels, not a detector: after a pause the re-boot waits for beta labelled no-touch chirps
    (a press right after the pause never enters the reference), as the first boot does."""
    beta, alpha, cps = 4, 50, 10.0
    t = np.r_[np.arange(20) / cps, 3600 + np.arange(20) / cps]
    X = np.r_[np.zeros((20, 1)), np.full((20, 1), 2.0)].astype(np.float32)
    touch = np.zeros(40, bool)
    touch[20:26] = True  # pressed straight after the pause
    X[20:26] += 10.0
    ref = OnlineReference(beta, alpha, cps, labelled=True)
    done = [i for i in range(40) if ref.step(X[i], t[i], bool(touch[i]))]
    assert done == [3, 29] and ref.reboots == 1  # chirps 26-29: the first four hands-off ones after the pause
    np.testing.assert_allclose(ref.features, [2.0])
    blind = OnlineReference(beta, alpha, cps)  # a detector's flags: the first beta chirps after the pause, by protocol
    assert [i for i in range(40) if blind.step(X[i], t[i], bool(touch[i]))] == [3, 23]


def _run(ref, X, t, predict):
    """Chirp by chirp as the live stream does: boot chirps get no prediction; returns each chirp's touch (None: boot)."""
    out = []
    for i in range(len(X)):
        if ref.booting_at(t[i]):
            ref.step(X[i], t[i])
            out.append(None)
            continue
        touched = bool(predict(ref.inputs(X[i][None])).touch[0])
        ref.step(X[i], t[i], touched)
        out.append(touched)
    return out


def _detector(inputs):
    from types import SimpleNamespace

    return SimpleNamespace(touch=np.abs(inputs).max(axis=1) > 1.0)


def test_a_hand_on_the_link_during_a_reboot_is_left_out_of_the_reference(rng):
    """Issue 37: touched chirps inside the re-boot's window poisoned the reference (every rest chirp then read touched,
    so no refresh came; boot_disturbed False).  Now they are found (far from the old reference by more than the pause
    moved every chirp), left out, and the re-boot is disturbed as one that lost chirps is: re-taken at the next rest."""
    beta, alpha, cps = 5, 200, 10.0
    t = np.r_[np.arange(20) / cps, 1500 + np.arange(120) / cps]  # a 25-min pause after 2 s
    X = (np.r_[np.zeros((20, 2)), np.full((120, 2), 2.0)] + rng.normal(0, 0.05, (140, 2))).astype(np.float32)
    X[21:24] += 10.0  # a hand on the link for 3 of the re-boot's 5 chirps (the wall also changed while off)
    a = OnlineReference(beta, alpha, cps)
    out = _run(a, X, t, _detector)
    assert a.reboots == 1 and a.last_gap_s == pytest.approx(1500 - 1.9)
    assert (a.boot_disturbed, a.boot_touched, a.boot_chirps) == (True, 3, 2)
    assert a.boot_cause == "a 25 min pause, 3 touched chirps left out"  # what the status line shows
    assert [i for i, o in enumerate(out) if o is None] == [0, 1, 2, 3, 4, 20, 21, 22, 23, 24]
    assert not any(out[25:]) and a.refreshes == 3  # every rest chirp reads quiet; re-taken from chirps 25-29
    np.testing.assert_allclose(a.features, X[25:30].mean(axis=0), rtol=1e-6)
    b = OnlineReference(beta, alpha, cps)  # the vectorised replay decides the same
    blocks = list(b.replay(X, t, _detector))
    assert [(lo, hi) for lo, hi, o in blocks if o is None] == [(0, 5), (20, 25)]
    assert (b.boot_touched, b.refreshes) == (3, a.refreshes)
    # a hand for all but one chirp of the window: too few at rest, so a new window from the next chirp
    c = OnlineReference(8, alpha, cps)
    X2 = X.copy()
    X2[20:27] += 10.0
    out = _run(c, X2, t, _detector)
    assert [i for i, o in enumerate(out) if o is None][8:] == list(range(20, 36)) and not any(out[36:])
    assert (c.boot_disturbed, c.boot_touched, c.boot_chirps) == (True, 7, 8)
    # a clean re-boot after the same pause is not disturbed
    d = OnlineReference(beta, alpha, cps)
    X3 = X.copy()
    X3[21:24] -= 10.0
    X3[40:49] += 10.0  # the hand came after the re-boot's window
    out = _run(d, X3, t, _detector)
    assert (d.boot_disturbed, d.boot_touched, d.boot_chirps) == (False, 0, 5) and [o for o in out[40:49]] == [True] * 9


def test_a_clock_going_back_is_a_new_stream_not_a_frozen_reference():
    """Issue 37: a clock going back an hour froze the reference (no refresh until the clock caught up); now a step back
    of more than one chirp period is a re-boot, so a wall that changed is followed at once."""
    beta, alpha, cps = 5, 50, 10.0
    t = np.r_[3600 + np.arange(100) / cps, np.arange(5 * alpha) / cps]  # back an hour after 10 s
    X = np.r_[np.zeros((100, 2)), np.full((5 * alpha, 2), 3.0)].astype(np.float32)
    a = OnlineReference(beta, alpha, cps)
    out = _run(a, X, t, _detector)
    assert a.reboots == 1 and a.last_gap_s == pytest.approx(-3609.9) and a.boot_cause == "the clock went back 3610 s"
    np.testing.assert_allclose(a.features, [3.0, 3.0])
    assert not any(o for o in out[105:])  # after the re-boot's window, the changed wall reads quiet
    b = OnlineReference(beta, alpha, cps)
    assert [(lo, hi) for lo, hi, o in b.replay(X, t, _detector) if o is None] == [(0, 5), (100, 105)]
    # a step back within one chirp period (timestamp jitter) is no new stream
    j = OnlineReference(beta, alpha, cps)
    _run(j, np.zeros((20, 2), np.float32), np.r_[np.arange(10) / cps, 0.85 + np.arange(10) / cps], _detector)
    assert j.reboots == 0 and j.refreshes == 1 and j.boot_cause == "power-on"


@pytest.mark.parametrize("bad", [float("nan"), float("inf"), -1.0, 1e308, "1.5", None, True, [1.0]])
def test_stream_time_is_checked_at_the_door_with_the_reference_unchanged(bad):
    """Issue 37: a NaN, inf or non-number time raised a raw ValueError/OverflowError/TypeError after changing state (a
    NaN in the boot stopped every later chirp).  Now: one SonicskinError line, nothing changed, the stream goes on."""
    import copy

    from sonicskin.errors import SonicskinError

    ref = OnlineReference(5, 50, 10.0)
    x = np.zeros(3, np.float32)
    for when in ("boot", "running"):
        before = copy.deepcopy(vars(ref))
        for call in (lambda: ref.step(x, bad), lambda: ref.booting_at(bad), lambda: ref.step(x, bad, False)):
            with pytest.raises(SonicskinError) as e:
                call()
            assert str(e.value).startswith("stream time t_s must be a number of seconds in 0..1e+12, got ")
            assert str(e.value).endswith("pass the chirp's time on the stream's clock, or skip a chirp whose time is unknown")
        after = vars(ref)
        assert before.keys() == after.keys() and all(np.array_equal(before[k], after[k]) if isinstance(before[k], np.ndarray)
                                                     else before[k] == after[k] for k in before if k != "_run")
        assert len(before["_run"]) == len(after["_run"])
        if when == "boot":
            assert [ref.step(x, i / 10) for i in range(5)] == [False] * 4 + [True]  # the boot completes as if nothing


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_features_are_refused_with_the_reference_unchanged(bad):
    """``step([nan, 1, 2], 0.0)`` in the boot was taken: the reference held NaN (Stream.chirp refused it, the class used
    directly did not).  Now: one SonicskinError line in the boot and after it, nothing changed, the stream goes on."""
    from sonicskin.errors import SonicskinError

    ref = OnlineReference(5, 50, 10.0)
    for when in ("boot", "running"):
        for touch in (None, False, True):
            with pytest.raises(SonicskinError) as e:
                ref.step(np.array([bad, 1.0, 2.0]), 0.7 if when == "running" else 0.0, touch)
            assert str(e.value) == ("the chirp's features hold NaN or infinite values (a NaN, silent or clipped frame); "
                                    "skip that chirp, as the live loop does")
        if when == "boot":
            assert ref._run == [] and ref._last_t is None and not ref.ready
            assert [ref.step(np.array([0.0, 1.0, 2.0]), i / 10) for i in range(5)] == [False] * 4 + [True]
    np.testing.assert_array_equal(ref.features, [0.0, 1.0, 2.0])
    assert ref.refreshes == 1 and ref._run == []
