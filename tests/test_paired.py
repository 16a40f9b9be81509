"""Seed-level statistics of arm comparisons (harness.scoring.paired): the paired t interval,
its p and the minimum detectable effect on tiny examples worked by hand, Holm's correction
on a small family worked by hand, and the coverage of the 95 % interval on synthetic
seeds-by-routes data with a known difference."""
from __future__ import annotations

import math

import numpy as np
import pytest

from harness.scoring.paired import bootstrap_p, holm, mde, t_interval


def test_paired_t_interval_and_p_of_three_seeds_by_hand():
    """d = 1, 2, 6: mean 3, squared deviations 4 + 1 + 9 = 14, variance 14 / 2 = 7, standard
    error sqrt(7 / 3) = 1.527525. With 2 degrees of freedom the t distribution function has the
    closed form F(t) = 1/2 + t / (2 sqrt(2 + t^2)), so t_{0.975, 2} solves t / sqrt(2 + t^2) =
    0.95: t = 0.95 sqrt(2) / sqrt(1 - 0.9025) = 4.302653; half width 4.302653 x 1.527525 =
    6.572411. t = 3 / 1.527525 has t^2 = 27 / 7, so the two-sided p = 1 - t / sqrt(2 + t^2) =
    1 - sqrt(27 / 41) = 0.188497."""
    mean, low, high, p = t_interval(np.array([1.0, 2.0, 6.0]))
    assert (mean, low, high) == pytest.approx((3.0, 3.0 - 6.572411, 3.0 + 6.572411), abs=1e-5)
    assert p == pytest.approx(1 - math.sqrt(27 / 41), abs=1e-6)


def test_a_difference_without_spread_is_its_own_interval():
    assert t_interval(np.array([5.0, 5.0, 5.0])) == (5.0, 5.0, 5.0, 0.0)
    assert t_interval(np.zeros(2))[3] == 1.0
    with pytest.raises(ValueError, match="two or more seeds"):
        t_interval(np.array([1.0]))


def test_minimum_detectable_effect_of_three_seeds_by_hand():
    """d = 1, 2, 6 (sd sqrt(7), n 3): MDE = (t_{0.975, 2} + t_{0.8, 2}) sqrt(7 / 3). By the
    closed form above t_{0.8, 2} solves t / sqrt(2 + t^2) = 0.6: t = 0.6 sqrt(2) / 0.8 =
    1.060660; (4.302653 + 1.060660) x 1.527525 = 8.192589."""
    assert mde(np.array([1.0, 2.0, 6.0])) == pytest.approx(8.192589, abs=1e-5)
    assert math.isnan(mde(np.array([1.0])))


def test_holm_on_a_small_family_by_hand():
    """p = 0.01, 0.04, 0.03, 0.005 (m = 4). In increasing order: 0.005 x 4 = 0.02, 0.01 x 3 =
    0.03, 0.03 x 2 = 0.06, 0.04 x 1 = 0.04 raised to the running maximum 0.06. At alpha 0.05
    the first and the fourth are rejected; the step-down stops at 0.03 (0.06 > 0.05), so 0.04
    is not, though it is below 0.05 alone. A NaN is no test of the family (m stays 4)."""
    assert holm([0.01, 0.04, 0.03, 0.005]) == pytest.approx([0.03, 0.06, 0.06, 0.02])
    out = holm([0.01, math.nan, 0.04, 0.03, 0.005])
    assert math.isnan(out[1]) and [out[i] for i in (0, 2, 3, 4)] == pytest.approx([0.03, 0.06, 0.06, 0.02])
    assert holm([0.6, 0.9]) == [1.0, 1.0]  # capped at 1


def test_bootstrap_p_is_twice_the_smaller_tail_at_zero():
    assert bootstrap_p(np.array([-1.0, 1.0, 2.0, 3.0])) == 0.5  # 1 of 4 at or below 0
    assert bootstrap_p(np.full(10, 5.0)) == 0.0
    assert bootstrap_p(np.zeros(3)) == 1.0


@pytest.mark.parametrize("n_seeds", [3, 20])
def test_the_95_interval_holds_the_true_difference_in_93_to_97_percent_of_1000_draws(n_seeds):
    """Two arms on n seeds x 100 routes: x[arm, seed, route] = mu_arm + seed effect (shared by
    both arms: the seed fixes initialisation and data order) + the arm's own seed effect +
    route effect (shared) + noise, with the spreads seen in the committed three-seed tables
    (seed 4.7 DS points, route 25, an arm's own seed effect 3, noise 15) and a true
    difference of 3.3. The interval is that of ``compare``: the t interval of the per-seed
    differences of the route means. Under this model the per-seed differences are normal with
    a common spread, so the coverage is 95 % exactly; 93-97 % is +-2.9 standard errors of a
    share of 1000 draws (sqrt(0.95 x 0.05 / 1000) = 0.69 %)."""
    rng = np.random.default_rng(20260 + n_seeds)
    draws, routes, delta = 1000, 100, 3.3
    mu = np.array([50.0, 50.0 + delta])[None, :, None, None]
    seed = rng.normal(0, 4.7, (draws, 1, n_seeds, 1))
    own = rng.normal(0, 3.0, (draws, 2, n_seeds, 1))
    route = rng.normal(0, 25.0, (draws, 1, 1, routes))
    x = mu + seed + own + route + rng.normal(0, 15.0, (draws, 2, n_seeds, routes))
    d = x[:, 1].mean(axis=2) - x[:, 0].mean(axis=2)  # (draws, seeds) per-seed differences
    held = [low <= delta <= high for _, low, high, _ in map(t_interval, d)]
    assert 0.93 <= np.mean(held) <= 0.97
