import numpy as np
import pytest
from sklearn.utils.estimator_checks import parametrize_with_checks

from sonicskin.ospa import OSPA


# The whole scikit-learn estimator contract for the single-input form fit(X) (MV = 1).
# Nothing is skipped: the two-input form (X_moving) is a keyword-only extra.
@parametrize_with_checks([OSPA(gamma=2)])
def test_sklearn_contract(estimator, check):
    check(estimator)


def test_ospa_picks_touch_sensitive_motion_insensitive_bins(rng):
    n, F = 400, 60
    touch = rng.normal(0, 1.0, (n, F))
    moving = rng.normal(0, 1.0, (n, F))
    touch[:, 10:20] *= 5.0  # touch-sensitive and quiet under motion: the answer
    touch[:, 30:40] *= 5.0  # touch-sensitive but motion-sensitive too
    moving[:, 30:40] *= 8.0
    moving[:, 50:60] *= 0.5  # quieter under motion, but touch-insensitive
    sel = OSPA(gamma=10).fit(touch, X_moving=moving)
    assert sorted(sel.get_support(indices=True)) == list(range(10, 20))
    assert np.allclose(sel.vc_, sel.mv_ / sel.tv_)
    assert sel.transform(touch).shape == (n, 10)
    # Without motion data it keeps the largest touch variance (both sensitive groups qualify).
    top = set(OSPA(gamma=20).fit(touch).get_support(indices=True))
    assert top == set(range(10, 20)) | set(range(30, 40))


def test_matched_filter_mask_is_respected(rng):
    X = rng.normal(size=(50, 20))
    X[:, :5] *= 10
    allowed = np.ones(20, bool); allowed[:5] = False
    sel = OSPA(gamma=5, allowed=allowed).fit(X)
    assert not set(sel.get_support(indices=True)) & set(range(5))
    assert np.all(np.isinf(sel.vc_[:5]))


def test_errors_name_the_problem(rng):
    X = rng.normal(size=(30, 8))
    with pytest.raises(ValueError, match="gamma=9 is larger than the 8 bins"):
        OSPA(gamma=9).fit(X)
    allowed = np.zeros(8, bool); allowed[:3] = True
    with pytest.raises(ValueError, match="larger than the 3 bins left after the matched filter"):
        OSPA(gamma=4, allowed=allowed).fit(X)
    with pytest.raises(ValueError, match="allowed mask has shape"):
        OSPA(gamma=2, allowed=np.ones(5, bool)).fit(X)
    with pytest.raises(ValueError, match=r"X_moving must be \(n_chirps, 8\)"):
        OSPA(gamma=2).fit(X, X_moving=np.ones((4, 7)))
    with pytest.raises(ValueError, match="positive integer"):
        OSPA(gamma=0).fit(X)
