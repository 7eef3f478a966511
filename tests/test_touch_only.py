"""Touch-only and no-force data: OSPA by touch variance, localization without rest, force absent (never 0 N), short rest."""

import warnings

import numpy as np
import pytest

from sonicskin.dataset import FeatureTable
from sonicskin.features import MIN_REST_CHIRPS, rest_beta
from sonicskin.kinds.closed import score_entry
from sonicskin.kinds.svm import SVMHead, fit_pipeline, ovo_decision, ovr_scores_from_ovo
from sonicskin.metrics import force_report
from sonicskin.ospa import select_bins
from sonicskin.rig import Layout, Rig

RIG = Rig(fs_hz=8000, f_lo_hz=1000, f_hi_hz=2000, n_chirp=400, pwm_hz=(), pwm_halfwidth_hz=0.0, name="small")


def _table(X, location, *, moving=None, force=None, session=None):
    n = len(location)
    return FeatureTable(np.asarray(X, np.float32), {
        "location": np.asarray(location), "moving": np.zeros(n) if moving is None else np.asarray(moving, float),
        "force_n": np.full(n, np.nan) if force is None else np.asarray(force, float),
        "session": np.full(n, "s000") if session is None else np.asarray(session), "time_s": np.arange(n) / 20.0})


def _locations(rng, n_per=40, k=3, noise=0.5):
    """Band features where bins 10-19 tell k locations apart (a bump per location) under noise."""
    loc = np.repeat(np.arange(k), n_per)
    X = rng.normal(0, noise, (loc.size, RIG.n_band)) - 40
    for j in range(k):
        X[loc == j, 10 + 3 * j: 13 + 3 * j] += 4.0
    return X, loc


def test_ospa_ranks_by_touch_variance_without_no_touch_chirps(rng):
    scale = np.geomspace(0.01, 100, RIG.n_band)  # touch variance grows with the bin index (x1.44 per bin)
    X = rng.normal(0, 1, (400, RIG.n_band)) * scale
    t = _table(X, np.repeat([0, 1], 200))
    got = select_bins(t, RIG, 10)
    np.testing.assert_array_equal(np.sort(got), np.arange(RIG.n_band - 10, RIG.n_band))
    # With moving no-touch chirps, a bin that also moves with the robot drops out.
    Xm = rng.normal(0, 1, (100, RIG.n_band))
    Xm[:, -1] *= 100
    t2 = _table(np.r_[X, Xm], np.r_[np.repeat([0, 1], 200), -np.ones(100, int)], moving=np.r_[np.zeros(400), np.ones(100)])
    assert RIG.n_band - 1 not in select_bins(t2, RIG, 10)


def test_gamma_larger_than_the_band_is_clamped(rng):
    X, loc = _locations(rng)
    with pytest.warns(UserWarning, match=f"using all {RIG.n_band}"):
        assert len(select_bins(_table(X, loc), RIG, 300)) == RIG.n_band
    with pytest.raises(ValueError, match="needs touch chirps"):
        select_bins(_table(X[:1], loc[:1]), RIG, 10)


def _paper_svm(X, loc, force, layout):
    """The paper's SVM on arrays: OSPA's 20 bins, the SVM head fitted without rest (the one fit's own function), and the
    head's decisions on new chirps (scikit-learn's pairwise scores, what the exported graph outputs)."""
    bins = select_bins(_table(X, loc), RIG, 20)
    pipe = fit_pipeline(X[:, bins], loc, len(layout))
    params = score_entry(ovr_scores_from_ovo(ovo_decision(pipe, X[:, bins]), len(layout)), X[:, bins], loc, force,
                         np.zeros(loc.size, bool), n_locations=len(layout), location_ids=layout.ids)
    head = SVMHead(params, layout)
    return params, lambda Z: head.decide([None, pipe.decision_function(Z[:, bins])], Z[:, bins])


def test_skin_svm_without_rest_or_force_sensor(rng):
    X, loc = _locations(rng)
    Xt, loct = _locations(rng)
    layout = Layout(ids=(0, 1, 2), xy_cm=np.array([[0, 0], [1, 0], [2, 0]]))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no divide-by-zero, no empty means
        params, predict = _paper_svm(X, loc, np.full(loc.size, np.nan), layout)
        p = predict(Xt)
    assert not params["detection"] and params["force"]["curves"] == {}
    assert np.mean(p.location == loct) > 0.95  # chance 33 %
    assert p.touch.all() and np.isnan(p.force_n).all()  # no detector: every chirp a touch; no force: NaN, not 0 N


def test_constant_force_is_no_force(rng):
    X, loc = _locations(rng)
    layout = Layout(ids=(0, 1, 2), xy_cm=np.array([[0, 0], [1, 0], [2, 0]]))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        params, predict = _paper_svm(X, loc, np.full(loc.size, 5.0), layout)
        assert params["force"]["curves"] == {} and np.isnan(predict(X).force_n).all()
        r = force_report(np.full(10, 5.0), np.full(10, 5.0))
    assert np.isnan(r["r2"]) and r["rmse_n"] == 0.0


def test_short_rest_is_used_down_to_the_minimum():
    def table(n_rest):
        loc = np.r_[-np.ones(n_rest, int), np.zeros(30, int), -np.ones(5, int), np.ones(30, int)]
        return _table(np.zeros((loc.size, RIG.n_band)), loc)

    assert rest_beta(table(40), 28) == 28
    with pytest.warns(UserWarning, match="27 consecutive hands-off chirps, fewer than beta = 28"):
        assert rest_beta(table(27), 28) == 27  # 3 s that start mid-chirp: 27 whole chirps
    assert rest_beta(table(MIN_REST_CHIRPS - 1), 28) is None
    # The shortest session decides (every stream needs its reference).
    both = _table(np.zeros((70, RIG.n_band)), np.r_[-np.ones(30, int), np.zeros(5, int), -np.ones(20, int), np.zeros(15, int)],
                  session=np.r_[np.full(35, "a"), np.full(35, "b")])
    with pytest.warns(UserWarning, match="session b has 20"):
        assert rest_beta(both, 28) == 20
