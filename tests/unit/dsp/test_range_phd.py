import numpy as np

from node_agent.dsp import RangeGmPhdFilter


def test_merges_extended_target_and_rejects_clutter(rng):
    phd = RangeGmPhdFilter(range_std=0.05, clutter_intensity=2.0 / 30.0)
    errs, counts = [], []
    for k in range(100):
        t = k / 50
        r_true = 6.0 + 1.5 * t
        # a body: three scatterers within 0.4 m around the true range, one missed at times
        body = r_true + np.array([-0.15, 0.0, 0.15]) + 0.02 * rng.standard_normal(3)
        body = body[rng.uniform(size=3) < 0.85]
        clutter = rng.uniform(2.0, 32.0, rng.poisson(2.0))
        z = np.concatenate((body, clutter))
        amps = np.concatenate((np.ones(body.size), 0.3 * np.ones(clutter.size)))
        est, est_amp = phd.step(t, z, amps)
        assert est.shape == est_amp.shape
        if k >= 10:
            counts.append(est.size)
            if est.size:
                errs.append(np.min(np.abs(est - r_true)))
    counts = np.array(counts)
    # one target: one estimate in most frames, clutter rarely confirmed
    assert np.mean(counts == 1) > 0.75
    assert np.mean(counts > 2) < 0.05
    assert np.median(errs) < 0.05


def test_two_separated_targets_per_channel_independent():
    phd = RangeGmPhdFilter(n_channels=2)
    for k in range(20):
        t = 0.02 * k
        out_r, _ = phd.step_channels(
            t, (np.array([5.0, 9.0]), np.array([5.2])), (np.ones(2), np.ones(1))
        )
    np.testing.assert_allclose(out_r[0], [5.0, 9.0], atol=1e-6)
    np.testing.assert_allclose(out_r[1], [5.2], atol=1e-6)
    # the missed-detection components carry (1 - pD) of the mass: the count of a
    # detected target settles at 1 / pD, which extraction rounds to 1
    n = phd.expected_count
    assert np.all(n >= [1.9, 0.95]) and np.all(n <= np.array([2, 1]) / phd.pd + 0.05)


def test_range_rate_and_flat_interface(rng):
    # the rate estimate is what pairs a person's ranges at two receivers: it must follow
    # the motion (process noise 0.5 m^2/s^3 and 5 cm ranges at 50 Hz: ~0.1 m/s)
    phd = RangeGmPhdFilter(n_channels=2, range_std=0.05, process_noise=0.5)
    rates = []
    for k in range(60):
        t = 10.0 + k / 50
        r = np.array([4.0 + 1.5 * (t - 10.0), 7.0 - 0.8 * (t - 10.0)])
        r += 0.02 * rng.standard_normal(2)
        est = phd.step_detections(t, r, np.ones(2), np.array([0, 1]))
        assert est.shape[1] == 5 and np.all(np.diff(est[:, 4]) >= 0)
        if k >= 30:
            rates.append(est[:, 2])
    rates = np.array(rates)
    np.testing.assert_allclose(np.median(rates, axis=0), [1.5, -0.8], atol=0.1)
    spans = phd.channel_spans(est)
    assert [b - a for a, b in spans] == [1, 1]
