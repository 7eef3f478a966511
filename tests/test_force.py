import numpy as np
import pytest

from sonicskin.force import MODELS, PerLocationForce, energy_db, fit_curve


@pytest.mark.parametrize("omega", [0.4, 1.3, 2.5])
def test_fourier1_recovers_known_parameters(rng, omega):
    E = rng.uniform(-6, 0, 400)  # dB
    a, b, c = 2.0, -1.5, 4.0
    F = a * np.cos(omega * E) + b * np.sin(omega * E) + c
    fit = fit_curve(E, F + rng.normal(0, 0.05, E.size), "fourier1")
    assert fit.r2 > 0.99
    grid = np.linspace(-6, 0, 50)
    np.testing.assert_allclose(fit.predict(grid), a * np.cos(omega * grid) + b * np.sin(omega * grid) + c, atol=0.08)


def test_rival_models_rank_by_r2_on_exponential_data(rng):
    E = rng.uniform(-3, 3, 300)
    F = 0.5 * np.exp(0.8 * E) + rng.normal(0, 0.05, E.size)
    r2 = {m: fit_curve(E, F, m).r2 for m in MODELS}
    assert r2["exp"] > 0.99
    assert r2["poly1"] < r2["poly2"] <= r2["poly3"] + 1e-9
    assert r2["exp"] >= max(r2["poly1"], r2["poly2"])


def test_per_location_roundtrip_and_errors(rng):
    E = rng.uniform(-5, 0, 200)
    loc = np.repeat([3, 7], 100)
    F = np.where(loc == 3, -E, -2 * E) + rng.normal(0, 0.01, E.size)
    m = PerLocationForce("poly1").fit(E, F, loc)
    again = PerLocationForce.from_dict(m.to_dict())
    np.testing.assert_allclose(again.predict(E, loc), m.predict(E, loc))
    np.testing.assert_allclose(m.predict(np.array([-1.0, -1.0]), np.array([3, 7])), [1.0, 2.0], atol=0.02)
    with pytest.raises(ValueError, match="unknown force model 'spline'"):
        PerLocationForce("spline")
    with pytest.raises(ValueError, match="equal length"):
        m.fit(E, F[:10], loc)
    with pytest.raises(ValueError, match="NaN"):
        fit_curve(np.r_[E[:9], np.nan], F[:10])


def test_energy_is_relative_to_reference():
    X = np.full((2, 6), -20.0)
    X[1] += 3.0
    e = energy_db(X, np.arange(6), ref_db=np.full(6, -20.0))
    np.testing.assert_allclose(e, [0.0, 3.0], atol=1e-9)


def test_curve_is_held_outside_its_training_range(rng):
    E = rng.uniform(-3, 0, 200)
    fit = fit_curve(E, E ** 3 + 5, "poly3")
    assert fit.predict(np.array([-30.0]))[0] == pytest.approx(fit.predict(np.array([E.min()]))[0])
    assert abs(fit.predict(np.array([-30.0]))[0]) < 30  # not (-30)^3
