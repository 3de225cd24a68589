import numpy as np
import pytest

from node_agent.dsp import (
    EllipseIntersector,
    RangePairAssociator,
    intersect_ellipses,
    pairing_threshold,
    position_covariance,
)


def ranges_of(p, tx, rx1, rx2):
    d = np.linalg.norm(p - tx, axis=-1)
    return d + np.linalg.norm(p - rx1, axis=-1), d + np.linalg.norm(p - rx2, axis=-1)


@pytest.mark.parametrize(
    ("tx", "rx1", "rx2"),
    [
        ((0.0, 0.0), (0.0, 0.5), (0.0, -0.5)),  # bat: collinear antennas
        ((3.0, -2.0), (3.4, -1.7), (2.1, -2.5)),  # arbitrary triangle
    ],
)
def test_exact_ranges_recover_point(rng, tx, rx1, rx2):
    tx, rx1, rx2 = map(np.asarray, (tx, rx1, rx2))
    truth = tx + rng.uniform(-8, 8, (200, 2))
    r1, r2 = ranges_of(truth, tx, rx1, rx2)
    pts, pair = intersect_ellipses(tx, rx1, rx2, r1, r2)
    err = np.full(truth.shape[0], np.inf)
    np.minimum.at(err, pair, np.linalg.norm(pts - truth[pair], axis=1))
    # rounding only: exact in general, micrometres where the ellipses are nearly tangent
    # (the square root of a discriminant near 0), far below one chip (4.3 cm)
    assert np.median(err) < 1e-10
    assert np.max(err) < 1e-5


def test_bat_mirror_images_and_front_selection():
    tx, rx1, rx2 = np.zeros(2), np.array([0.0, 0.5]), np.array([0.0, -0.5])
    p = np.array([[4.0, 1.0]])
    pts, pair = intersect_ellipses(tx, rx1, rx2, *ranges_of(p, tx, rx1, rx2))
    np.testing.assert_allclose(np.sort(pts[:, 0]), [-4.0, 4.0], atol=1e-9)
    np.testing.assert_allclose(pts[:, 1], [1.0, 1.0], atol=1e-9)
    np.testing.assert_array_equal(pair, [0, 0])


def test_chip_level_range_errors_give_cm_level_positions(rng):
    tx, rx1, rx2 = np.zeros(2), np.array([0.0, 0.5]), np.array([0.0, -0.5])
    truth = np.column_stack((rng.uniform(2, 5, 500), rng.uniform(-1.5, 1.5, 500)))
    r1, r2 = ranges_of(truth, tx, rx1, rx2)
    sigma = 0.01  # a quarter chip (interpolated peaks)
    pts, pair = intersect_ellipses(
        tx, rx1, rx2, r1 + sigma * rng.standard_normal(500), r2 + sigma * rng.standard_normal(500)
    )
    front = pts[:, 0] > 0
    err = np.linalg.norm(pts[front] - truth[pair[front]], axis=1)
    # range errors of sigma map to ~sigma along range and sigma * sqrt(2) * d / baseline
    # across it: a few cm at 2-5 m from a 1 m baseline
    assert np.median(err) < 0.1
    cov, ok = position_covariance(pts[front], tx, rx1, rx2, sigma)
    assert ok.all()
    # the predicted spread matches the observed errors (chi-square with 2 dof)
    e = pts[front] - truth[pair[front]]
    m2 = np.einsum("ki,ki->k", e, np.linalg.solve(cov, e[..., None])[..., 0])
    assert 1.0 < np.mean(m2) < 3.5


def test_no_intersection_is_dropped():
    tx, rx1, rx2 = np.zeros(2), np.array([0.0, 0.5]), np.array([0.0, -0.5])
    # |r1 - r2| larger than the baseline: no point has these ranges
    pts, pair = intersect_ellipses(tx, rx1, rx2, np.array([6.0, 6.0]), np.array([8.0, 6.1]))
    assert set(pair.tolist()) == {1}
    assert pts.shape == (2, 2)


def test_association_pairs_two_targets():
    tx, rx1, rx2 = np.zeros(2), np.array([0.0, 0.5]), np.array([0.0, -0.5])
    targets = np.array([[3.0, 1.0], [4.5, -1.2]])
    r1, r2 = ranges_of(targets, tx, rx1, rx2)
    assoc = RangePairAssociator(pairing_threshold(rx1, rx2, margin=0.1))
    # receiver 2 lists them in the other order and has one clutter range
    r2_list = np.array([r2[1], 30.0, r2[0]])
    i1, i2 = assoc.associate(r1, r2_list)
    pairs = dict(zip(i1.tolist(), i2.tolist(), strict=True))
    assert pairs == {0: 2, 1: 0}


def test_association_respects_threshold():
    assoc = RangePairAssociator(1.1)
    i1, i2 = assoc.associate(np.array([5.0]), np.array([6.5]))
    assert i1.size == 0 and i2.size == 0


def test_closed_form_covariance_matches_information_inverse(rng):
    tx, rx1, rx2 = np.zeros(2), np.array([0.0, 0.5]), np.array([0.0, -0.5])
    pts = np.column_stack((rng.uniform(1, 8, 50), rng.uniform(-4, 4, 50)))
    cov, ok = position_covariance(pts, tx, rx1, rx2, 0.05)
    assert ok.all()
    # reference: (J^T R^-1 J)^-1 from the Jacobian of the two ranges, by solve
    u = [(pts - a) / np.linalg.norm(pts - a, axis=1)[:, None] for a in (tx, rx1, rx2)]
    jac = np.stack((u[0] + u[1], u[0] + u[2]), axis=1)
    info = np.einsum("kri,krj->kij", jac, jac) / 0.05**2
    ref = np.linalg.solve(info, np.broadcast_to(np.eye(2), info.shape))
    np.testing.assert_allclose(cov, ref, rtol=1e-9, atol=1e-15)
    # on the antennas' line the geometry is singular
    _, ok = position_covariance(np.array([[0.0, 3.0]]), tx, rx1, rx2, 0.05)
    assert not ok.any()


def test_collinear_and_general_intersection_agree(rng):
    # exactly on the bat's line the collinear path; 1 mm off it (an angle of 2e-3 at tx)
    # the general one, whose inverse is then ill-conditioned (1/angle): still far below
    # a chip (4.3 cm), micrometres
    tx, rx1 = np.zeros(2), np.array([0.0, 0.5])
    truth = np.column_stack((rng.uniform(1, 6, 100), rng.uniform(-3, 3, 100)))
    for rx2, tol in ((np.array([0.0, -0.5]), 1e-9), (np.array([1e-3, -0.5]), 1e-6)):
        r1, r2 = ranges_of(truth, tx, rx1, rx2)
        pts, pair = intersect_ellipses(tx, rx1, rx2, r1, r2)
        front = pts[:, 0] > 0
        err = np.linalg.norm(pts[front] - truth[pair[front]], axis=1)
        assert np.median(err) < tol and pair[front].size == 100


def test_association_pairs_by_range_rate_not_smallest_difference():
    # two people 4 m away on either side of the axis, at mirror positions: receiver 1's
    # range of one equals receiver 2's range of the other, so the smallest-difference
    # pairing is the swapped one, whose ellipses meet on the axis (two ghosts)
    tx, rx1, rx2 = np.zeros(2), np.array([0.0, 0.5]), np.array([0.0, -0.5])
    people = np.array([[4.0, 1.0], [4.0, -1.0]])
    r1, r2 = ranges_of(people, tx, rx1, rx2)
    assoc = RangePairAssociator(pairing_threshold(rx1, rx2, margin=0.15))
    r2_listed = r2[::-1] + np.array([0.0, 0.02])  # receiver 2 lists them the other way
    swapped = assoc.associate(r1, r2_listed)  # ranges alone: the ghost pairing
    assert swapped[1].tolist() == [0, 1]
    # one walks towards the sensor, the other away: their range rates tell them apart
    var, amp = np.full(2, 0.01), np.ones(2)
    feat1 = np.array([var, [-1.0, 1.0], amp])
    feat2 = np.array([var, [1.0, -1.0], amp])
    i1, i2 = assoc.associate(r1, r2_listed, feat1, feat2)
    assert dict(zip(i1.tolist(), i2.tolist(), strict=True)) == {0: 1, 1: 0}


@pytest.mark.parametrize(
    "antennas",
    [
        ((0.0, 0.0), (0.0, 0.5), (0.0, -0.5)),  # bat: collinear antennas
        ((0.0, 0.0), (1.0, 0.2), (-0.3, 1.1)),
    ],
)
def test_scalar_locate_matches_vectorized(rng, antennas):
    tx, rx1, rx2 = (np.array(a) for a in antennas)
    p = rng.uniform(-5.0, 5.0, size=(40, 2))
    r1, r2 = ranges_of(p, tx, rx1, rx2)
    r1 = r1 + rng.normal(0.0, 0.2, r1.size)  # some pairs then have no intersection
    ell = EllipseIntersector(tx, rx1, rx2)
    pts, _ = ell.intersect(np.array((r1, r2)))
    cov, ok = ell.covariance(pts, 0.05)
    got = np.array(ell.locate(r1.tolist(), r2.tolist(), 0.05)).reshape(-1, 5)
    np.testing.assert_allclose(got[:, :2], pts[ok], rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(got[:, (2, 3, 3, 4)].reshape(-1, 2, 2), cov[ok], rtol=1e-9)
