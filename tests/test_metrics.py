import numpy as np
import pytest

from sonicskin.metrics import error_cdf, force_report, localization_report
from sonicskin.rig import Layout


def test_localization_report_known_answers():
    lay = Layout.grid(4, 1, 1.2)
    r = localization_report(np.array([0, 1, 2, 3]), np.array([0, 2, 2, 0]), lay)
    assert r["accuracy"] == 0.5
    np.testing.assert_allclose(r["errors_cm"], [0, 1.2, 0, 3.6])
    assert r["within_2cm"] == 0.75 and r["within_3cm"] == 0.75
    assert r["confusion"][1][2] == 1
    e, c = error_cdf(r["errors_cm"])
    assert list(c) == [0.25, 0.5, 0.75, 1.0] and e[-1] == pytest.approx(3.6)


def test_force_report_table_one():
    g = np.array([1.0, 2.0, 3.0, 4.0])
    r = force_report(g, g + np.array([0.5, -0.5, 0.5, -0.5]))
    assert r["rmse_n"] == pytest.approx(0.5) and r["sigma_n"] == pytest.approx(0.5)
    assert force_report(g, g)["xcorr"] == pytest.approx(1.0)
    with pytest.raises(ValueError, match="4 true forces but 3 predictions"):
        force_report(g, g[:3])


def test_force_report_scores_only_the_chirps_with_a_measured_force():
    # A force sensor that logged part of the time: the chirps without a force are left out, and counted, not NaN.
    r = force_report(np.array([1.0, np.nan, 3.0, np.nan]), np.array([1.5, 9.0, 2.5, 9.0]))
    assert r["n"] == 2 and r["n_unmeasured"] == 2 and r["rmse_n"] == pytest.approx(0.5)
    assert "n_unmeasured" not in force_report(np.array([1.0, 3.0]), np.array([1.5, 2.5]))
