"""Lab-test measurements on synthetic curves with known answers (compression positive)."""
import math

import numpy as np
import pytest

from geodem.measure import (
    brazilian_tensile_strength,
    crack_start_offset,
    elastic_window,
    mohr_coulomb_fit,
    peak,
    poisson_ratio,
    youngs_modulus,
)

E, NU, UCS = 3.0e10, 0.21, 1.2e8
EPS_P = UCS / E  # 4e-3: the peak lies on a grid point


def curve(noise=0.0, seed=0):
    """Linear elastic up to the peak, then linear softening to 40 % of the peak."""
    eps = np.linspace(0.0, 2 * EPS_P, 2001)  # step 4e-6; eps[1000] == EPS_P
    sig = np.where(eps <= EPS_P, E * eps, UCS - 0.6 * UCS * (eps - EPS_P) / EPS_P)
    lat = -NU * eps
    rng = np.random.default_rng(seed)
    return (eps, sig + noise * UCS * rng.standard_normal(eps.size),
            lat + noise * EPS_P * NU * rng.standard_normal(eps.size))


def test_noiseless_curve_exact():
    eps, sig, lat = curve()
    assert youngs_modulus(eps, sig) == pytest.approx(E, rel=1e-9)
    assert poisson_ratio(eps, lat, stress=sig) == pytest.approx(NU, abs=1e-12)
    assert poisson_ratio(eps, lat) == pytest.approx(NU, abs=1e-12)
    ucs, ep = peak(eps, sig)
    assert ucs == pytest.approx(UCS, rel=1e-12) and ep == pytest.approx(EPS_P, rel=1e-9)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_noisy_curve_within_tolerance(seed):
    eps, sig, lat = curve(noise=0.005, seed=seed)
    assert youngs_modulus(eps, sig) == pytest.approx(E, rel=0.01)
    assert poisson_ratio(eps, lat, (0.1, 0.5), stress=sig) == pytest.approx(NU, abs=0.005)
    ucs, ep = peak(eps, sig)  # the peak is the largest recorded stress, exactly
    i = int(np.argmax(sig))
    assert ucs == sig[i] and ep == eps[i]
    assert ucs == pytest.approx(UCS, rel=0.03)


def test_window_is_pre_peak_only():
    # post-peak softening passes through the same stress band: it must not enter the E fit
    eps, sig, _ = curve()
    assert youngs_modulus(eps, sig, window=(0.45, 0.95)) == pytest.approx(E, rel=1e-9)


def damaged_curve():
    """Elastic (E, NU) up to 0.3 of the peak, where bonds begin to break (10 of 1,000 by 0.4
    of the peak, 200 at the peak); beyond 0.3 the lateral strain grows four times faster
    (crack dilation), as in a bonded packing that cracks diffusely before its peak."""
    eps, sig, _ = curve()
    ci = 0.3 * UCS / E
    lat = -NU * eps - np.where(eps > ci, 3.0 * NU * (eps - ci), 0.0)
    cracks = np.where(eps > ci, np.floor(200 * (eps - ci) / (EPS_P - ci)), 0.0)
    cracks[eps > EPS_P] = 200
    return eps, sig, lat, cracks


def test_elastic_window_stops_where_the_bonds_begin_to_break():
    eps, sig, lat, cracks = damaged_curve()
    # 0.5 % of 1,000 bonds = 5 cracks: reached at eps - ci = 5/200 (EPS_P - ci)
    lo, hi, sci = elastic_window(sig, cracks, 1000)
    eps_5 = 0.3 * EPS_P + 6 / 200 * 0.7 * EPS_P  # the first point with 6 > 5 cracks
    assert lo == 0.1
    assert sci == pytest.approx(E * (eps_5 - 4e-6), rel=1e-3)  # the point before it
    assert hi == pytest.approx(sci / UCS, rel=1e-12)
    # the few points between the first crack (0.3) and the threshold (0.321) dilate a little
    assert poisson_ratio(eps, lat, (lo, hi), stress=sig) == pytest.approx(NU, abs=0.02)
    assert poisson_ratio(eps, lat, (0.1, 0.3), stress=sig) == pytest.approx(NU, abs=1e-9)
    # the fixed 10-50 % window measures the dilation: the least-squares slope of
    # max(0, x - 0.3) over x uniform in 0.1-0.5 is 1/2, so nu = NU (1 + 3/2) = 0.525
    nu_fixed = poisson_ratio(eps, lat, (0.1, 0.5), stress=sig)
    assert nu_fixed == pytest.approx(2.5 * NU, rel=0.01)


def test_a_packing_that_cracks_early_is_fitted_below_its_crack_initiation():
    """Cracks from 6 % of the peak (before the window's 10 %): the fit runs from 3 % to 6 %,
    on the elastic part, instead of three cracked points above 10 %."""
    eps, sig, _ = curve()
    ci = 0.06 * UCS / E
    lat = -NU * eps - np.where(eps > ci, 3.0 * NU * (eps - ci), 0.0)
    cracks = np.where(eps > ci, 100.0, 0.0)
    lo, hi, sci = elastic_window(sig, cracks, 1000)
    assert hi == pytest.approx(0.06, abs=2e-3) and lo == pytest.approx(hi / 2)
    assert poisson_ratio(eps, lat, (lo, hi), stress=sig) == pytest.approx(NU, rel=1e-6)


def test_elastic_window_without_damage_or_threshold_keeps_the_window():
    eps, sig, _, cracks = damaged_curve()
    assert elastic_window(sig, np.zeros_like(sig), 1000) == (0.1, 0.5, None)
    assert elastic_window(sig, cracks, 1000, crack_fraction=None) == (0.1, 0.5, None)
    assert elastic_window(sig, cracks, 1e6)[1:] == (0.5, None)  # 0.5 % of 1e6: never reached


def test_elastic_window_keeps_three_points_and_refuses_bad_input():
    sig = np.array([0.0, 1.0, 2.0, 3.0, 4.0, 10.0])
    cracks = np.array([0, 50, 60, 70, 80, 90.0])  # the threshold is passed at the 2nd point
    lo, hi, sci = elastic_window(sig, cracks, 1000, window=(0.05, 0.5))
    assert sci == 0.0 and lo == 0.0 and hi == pytest.approx(0.2)  # 3 points: 0, 1, 2 / 10
    with pytest.raises(ValueError, match="differ in length"):
        elastic_window(sig, cracks[:3], 1000)
    with pytest.raises(ValueError, match="allowed bonds > 0"):
        elastic_window(sig, cracks, 0)


def test_brazilian():
    P, D, t = 2.0e4, 0.05, 0.025
    assert brazilian_tensile_strength(P, D, t) == pytest.approx(2 * P / (math.pi * D * t))
    assert brazilian_tensile_strength(math.pi, 1.0, 1.0) == pytest.approx(2.0)
    for bad in ((0.0, D, t), (P, -D, t), (P, D, float("nan"))):
        with pytest.raises(ValueError, match=r"must be a finite number > 0"):
            brazilian_tensile_strength(*bad)


def test_crack_start_offset():
    c = np.array([1.0, 2.0])
    r = 0.5
    ang = np.linspace(0, 2 * np.pi, 10, endpoint=False)
    first = c + 0.1 * np.c_[np.cos(ang), np.sin(ang)]  # 10 cracks at 0.1 from the centre
    later = c + 0.45 * np.c_[np.cos(ang), np.sin(ang)]
    xy = np.vstack([first, later])
    assert crack_start_offset(xy, c, r, k=10) == pytest.approx(0.2)
    assert crack_start_offset(xy, c, r, k=20) == pytest.approx((0.1 + 0.45) / 2 / r)
    assert crack_start_offset(first[:3], c, r, k=10) == pytest.approx(0.2)  # fewer than k
    with pytest.raises(ValueError, match=r"shape \(n, 2\)"):
        crack_start_offset(np.zeros((3, 3)), c, r)
    with pytest.raises(ValueError, match="empty"):
        crack_start_offset(np.zeros((0, 2)), c, r)
    with pytest.raises(ValueError, match="radius"):
        crack_start_offset(first, c, 0.0)


def _mc_data(c, phi_deg, s3):
    p = math.radians(phi_deg)
    q = math.tan(math.radians(45 + phi_deg / 2)) ** 2
    cu = 2 * c * math.cos(p) / (1 - math.sin(p))
    return cu, cu + q * np.asarray(s3)


def test_mohr_coulomb_exact():
    s3 = np.array([0.0, 5e6, 10e6, 20e6, 40e6])
    cu, s1 = _mc_data(2.0e7, 35.0, s3)
    c, phi, cu_fit = mohr_coulomb_fit(s3, s1)
    assert c == pytest.approx(2.0e7, rel=1e-10)
    assert phi == pytest.approx(35.0, abs=1e-9)
    assert cu_fit == pytest.approx(cu, rel=1e-10)
    c2, phi2, _ = mohr_coulomb_fit(s3[:2], s1[:2])  # two points: exact line
    assert c2 == pytest.approx(2.0e7, rel=1e-10) and phi2 == pytest.approx(35.0, abs=1e-9)


def test_mohr_coulomb_noise():
    rng = np.random.default_rng(3)
    s3 = np.repeat([0.0, 10e6, 20e6, 30e6, 40e6], 4)
    cu, s1 = _mc_data(3.0e7, 45.0, s3)
    s1 = s1 * (1 + 0.01 * rng.standard_normal(s1.size))
    c, phi, cu_fit = mohr_coulomb_fit(s3, s1)
    assert phi == pytest.approx(45.0, abs=1.0)
    assert c == pytest.approx(3.0e7, rel=0.05)
    assert cu_fit == pytest.approx(cu, rel=0.03)


@pytest.mark.parametrize("args,match", [
    (([0, 1, 2], [0, 1]), r"same length, got 3 and 2"),
    (([0, 1], [0, 1]), r"at least 3 points"),
    (([0, 2, 1, 3], [0, 1, 2, 3]), r"must increase strictly .* index 2"),
    (([0, 1, 2, np.nan], [0, 1, 2, 3]), r"non-finite"),
    (([[0, 1, 2]], [[0, 1, 2]]), r"1-D"),
    ((np.arange(5.0), -np.arange(5.0)), r"no compressive loading"),
])
def test_bad_curves(args, match):
    with pytest.raises(ValueError, match=match):
        youngs_modulus(*args)


def test_bad_window_and_too_few_points():
    eps, sig, lat = curve()
    with pytest.raises(ValueError, match=r"allowed 0 <= lo < hi <= 1"):
        youngs_modulus(eps, sig, window=(0.5, 0.1))
    with pytest.raises(ValueError, match=r"pair"):
        youngs_modulus(eps, sig, window=0.5)
    e = np.array([0.0, 1e-3, 2e-3, 3e-3, 4e-3])
    with pytest.raises(ValueError, match=r"only 1 pre-peak points .* need >= 3"):
        youngs_modulus(e, E * e, window=(0.3, 0.6))
    with pytest.raises(ValueError, match=r"same length"):
        poisson_ratio(eps, lat[:-1])
    with pytest.raises(ValueError, match=r"at least 1 points"):
        peak([], [])


def test_mohr_coulomb_bad_input():
    with pytest.raises(ValueError, match=r"two different confining"):
        mohr_coulomb_fit([1e6, 1e6], [5e7, 6e7])
    with pytest.raises(ValueError, match=r"at least 2 points"):
        mohr_coulomb_fit([1e6], [5e7])
    with pytest.raises(ValueError, match=r"sigma1 < sigma3 at index 1"):
        mohr_coulomb_fit([0.0, 1e8], [5e7, 6e7])
    with pytest.raises(ValueError, match=r"negative friction"):
        mohr_coulomb_fit([0.0, 1e7], [5e7, 5.5e7])
