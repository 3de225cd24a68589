"""Measurement models of Fig. 19: ranges, Jacobians and inverses against geometry."""

from __future__ import annotations

import ast
from pathlib import Path

import numpy as np
import pytest

from fusion_center.mapping.models import (
    CORNER,
    POINT,
    WALL,
    invert_image,
    invert_point,
    predict,
    states_from_image,
)

RX_BODY = np.array([[0.0, 0.5], [0.0, -0.5]])


def _mirror(p: np.ndarray, a: np.ndarray, n: np.ndarray) -> np.ndarray:
    return p - 2 * np.dot(p - a, n) * n


def test_wall_range_is_the_mirror_image_path() -> None:
    tx = np.array([1.0, 2.0])
    rx = np.array([[1.0, 2.5], [1.0, 1.5]])
    # the wall x = 4 (normal +x, distance 4)
    r, _, d = predict(WALL, np.array([0.0, 4.0]), tx, rx)
    img = _mirror(tx, np.array([4.0, 0.0]), np.array([1.0, 0.0]))
    assert np.allclose(r, np.linalg.norm(img - rx, axis=1))
    assert np.allclose(d, [1.0, 0.0])


def test_corner_range_is_the_double_reflection_path() -> None:
    tx = np.array([1.0, 1.0])
    rx = np.array([[0.6, 1.3], [1.4, 0.7]])
    c = np.array([3.0, 4.0])
    # double reflection in the walls x = 3 and y = 4: image of the image
    img = _mirror(_mirror(tx, c, np.array([1.0, 0.0])), c, np.array([0.0, 1.0]))
    r, _, _ = predict(CORNER, c, tx, rx)
    assert np.allclose(r, np.linalg.norm(img - rx, axis=1))


@pytest.mark.parametrize("kind", [WALL, CORNER, POINT])
def test_jacobians_match_finite_differences(kind: int, rng: np.random.Generator) -> None:
    tx = rng.normal(size=(5, 2))
    rx = tx[:, None, :] + rng.normal(scale=0.5, size=(5, 2, 2))
    if kind == WALL:
        state = np.column_stack([rng.uniform(-np.pi, np.pi, 5), rng.uniform(3, 6, 5)])
    else:
        state = rng.uniform(3, 6, (5, 2))
    _, jac, _ = predict(kind, state, tx, rx)
    eps = 1e-6
    for i in range(2):
        d = np.zeros(2)
        d[i] = eps
        num = (predict(kind, state + d, tx, rx)[0] - predict(kind, state - d, tx, rx)[0]) / (
            2 * eps
        )
        assert np.allclose(jac[..., i], num, atol=1e-5)


def test_inverses_recover_landmarks_in_the_array_frame(rng: np.random.Generator) -> None:
    origin = np.zeros(2)
    pts = np.column_stack([rng.uniform(1, 6, 50), rng.uniform(-2, 2, 50)])
    r, _, _ = predict(POINT, pts, origin, RX_BODY)
    assert np.allclose(invert_point(r, RX_BODY), pts, atol=1e-6)
    r, _, _ = predict(CORNER, pts, origin, RX_BODY)
    img = invert_image(r, RX_BODY)
    assert np.allclose(states_from_image(CORNER, img, origin), pts, atol=1e-9)
    # a wall from its image: normal towards it, line halfway
    wall = states_from_image(WALL, img, origin)
    r2, _, _ = predict(WALL, wall, origin, RX_BODY)
    assert np.allclose(r2, r, atol=1e-9)


def test_inverse_rejects_impossible_pairs() -> None:
    # ranges differing by more than the baseline: no intersection
    assert np.all(np.isnan(invert_image(np.array([[3.0, 4.5]]), RX_BODY)))


def test_mapping_core_imports_nothing_impure() -> None:
    root = Path(__file__).resolve().parents[3] / "fusion_center" / "mapping"
    forbidden = {"zenoh", "msgpack", "mcap", "serial", "time", "datetime", "socket", "threading"}
    for path in root.glob("*.py"):
        tree = ast.parse(path.read_text())
        imported = set()
        for node in ast.walk(tree):
            if isinstance(node, ast.Import):
                imported |= {a.name.split(".")[0] for a in node.names}
            elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                imported.add(node.module.split(".")[0])
        assert not imported & forbidden, f"{path.name} imports {sorted(imported & forbidden)}"
