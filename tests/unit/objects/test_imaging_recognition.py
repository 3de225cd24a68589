"""Fuzzy RPM imaging (Section 7.5) and CSS recognition (7.7) on simulated circular scans."""

from __future__ import annotations

import numpy as np
import pytest

from fusion_center.objects.alphabet import alphabet, place, polygon_centroid
from fusion_center.objects.fuzzy import FuzzyRpmImager, circle_intersections, monostatic_distance
from fusion_center.objects.recognition import (
    CssConfig,
    CssRecognizer,
    circular_correlation,
    describe,
    hu_moments,
    resample_contour,
)
from sim_nodes.channel.prism import PrismTarget
from sim_nodes.circle_scan import CircleTrack, geometric_wavefronts, scan_echoes
from uwbnet.bench_objects import _edge_distance
from uwbnet.objects_cmd import reference_contours, scan_contour


def test_alphabet_has_twelve_ccw_polygons_centred() -> None:
    shapes = alphabet()
    assert len(shapes) == 12
    for v in shapes.values():
        area = 0.5 * np.sum(v[:, 0] * np.roll(v[:, 1], -1) - np.roll(v[:, 0], -1) * v[:, 1])
        assert area > 0.01
        assert np.allclose(polygon_centroid(v), 0.0, atol=1e-12)


def test_law_of_cosines_intersection_finds_the_point() -> None:
    p = np.array([0.3, -0.1])
    s_i, s_j = np.array([1.0, 0.0]), np.array([0.98, 0.2])
    got = circle_intersections(
        s_i, np.linalg.norm(p - s_i), s_j, np.linalg.norm(p - s_j), np.array([-1.0, 0.0])
    )
    assert np.allclose(got, p, atol=1e-12)
    # Circles that do not meet give NaN, not a made-up point.
    assert np.isnan(circle_intersections(s_i, 0.1, s_j, 0.1, np.array([-1.0, 0.0]))).all()


def test_fuzzy_contour_lies_on_the_object() -> None:
    rng = np.random.default_rng(0)
    verts = place(alphabet()["rect_30x45"], 0.4, (0.08, -0.05))
    track = CircleTrack()
    contour = scan_contour(verts, track, rng, range_noise=0.002)
    err = _edge_distance(contour, verts)
    assert len(contour) > 300  # nearly every position images the front surface
    assert np.median(err) < 0.005
    assert np.percentile(err, 95) < 0.02


def test_stacked_scans_image_in_3d() -> None:
    # Three layers of a square prism at heights 0.9, 1.0, 1.1 m: the 3-D points lie on its
    # faces and at the layer heights.
    rng = np.random.default_rng(1)
    verts = alphabet()["square_30"]
    heights = (0.9, 1.0, 1.1)
    pos, dist, tow = [], [], []
    for z in heights:
        track = CircleTrack(height=z, step=np.deg2rad(2.0))
        ranges = geometric_wavefronts(
            scan_echoes(PrismTarget(vertices=verts), track, np.deg2rad(70.0)), rng
        )
        p2 = track.positions()
        pos.append(np.column_stack([p2, np.full(len(p2), z)]))
        dist.append(monostatic_distance(ranges, track.baseline))
        t2 = track.antennas()[2]
        tow.append(np.column_stack([t2, np.zeros(len(t2))]))
    pts, mu = FuzzyRpmImager().image_3d(np.array(pos), np.array(dist), np.array(tow), closed=True)
    first = pts[:, :, 0, :]
    ok = np.isfinite(first[..., 0])
    assert ok.mean() > 0.8
    err = _edge_distance(first[ok][:, :2], verts)
    assert np.median(err) < 0.01
    # A vertical face answers every layer at the same distance, so the three-sphere point of
    # layer l sits between l and its elevation neighbour: within the scanned heights.
    z = first[..., 2][ok]
    assert z.min() > 0.9 - 0.01
    assert z.max() < 1.1 + 0.01
    assert (mu[..., 0][ok] > 0).all()


def test_css_distance_is_zero_for_a_shifted_copy_and_positive_otherwise() -> None:
    cfg = CssConfig()
    sq = describe(resample_contour(alphabet()["square_30"], 0.005, closed=True), cfg, closed=True)
    tri = describe(
        resample_contour(alphabet()["triangle_eq45"], 0.005, closed=True), cfg, closed=True
    )
    shifted = np.roll(sq.css, 37, axis=1)
    assert circular_correlation(shifted, sq.css) == pytest.approx(0.0, abs=1e-9)
    assert circular_correlation(tri.css, sq.css) > 0.2


def test_hu_moments_invariant_to_rotation_translation_and_scale() -> None:
    v = alphabet()["L_50x30"]
    a, b = hu_moments(v), hu_moments(2.0 * place(v, 1.1, (3.0, -2.0)))
    assert np.allclose(a, b, atol=1e-6)
    assert not np.allclose(a, hu_moments(alphabet()["T_50"]), atol=0.05)


@pytest.fixture(scope="module")
def recognizer() -> CssRecognizer:
    return CssRecognizer(reference_contours(1.0, 0.1, n_rotations=2))


@pytest.mark.parametrize("name", ["square_45", "triangle_right", "L_45", "T_50", "hexagon_long"])
def test_full_track_recognition(recognizer: CssRecognizer, name: str) -> None:
    rng = np.random.default_rng(5)
    verts = place(alphabet()[name], rng.uniform(0, 2 * np.pi), (0.12, -0.1))
    contour = scan_contour(verts, CircleTrack(), rng)
    assert recognizer.classify(contour, closed=True) == name


def test_partial_track_recognition(recognizer: CssRecognizer) -> None:
    rng = np.random.default_rng(6)
    verts = place(alphabet()["hexagon_25"], 0.3, (-0.1, 0.05))
    track = CircleTrack(start=1.0, span=np.deg2rad(270.0))
    contour = scan_contour(verts, track, rng)
    assert not track.closed
    assert recognizer.classify(contour, closed=False) == "hexagon_25"


def test_describe_rejects_too_few_points() -> None:
    with pytest.raises(ValueError, match="at least 4"):
        describe(np.zeros((2, 2)), CssConfig(), closed=True)
