"""The compiled people-echo kernel against the numpy reference (scatterers + scatter_paths)."""

from __future__ import annotations

import numpy as np
import pytest

from sim_nodes.channel import Antennas, Crowd, Walls, make_walker, scatter_paths, wall_side
from sim_nodes.channel.kernels import body_echo_paths
from sim_nodes.radar import C

SHADOW_DB = 18.0


def _crowd(rng: np.random.Generator) -> Crowd:
    # Four people walking along x at y = 0.3 (in line with the node: they shadow each other),
    # one crossing the wall at x = 4, one that has left, one far away.
    def walker(pid: int, wp: list[tuple[float, float]], **kw: float) -> object:
        return make_walker(
            person_id=pid,
            waypoints=wp,
            speed=1.1 + 0.1 * pid,
            bounce=True,
            enter=kw.get("enter", 0.0),
            leave=kw.get("leave"),
            radius=0.25,
            rcs=1.0,
            height=1.2,
            n_scatterers=6,
            breathing_rate=0.25,
            rng=rng,
        )

    return Crowd(
        [
            walker(0, [(1.5, 0.3), (3.5, 0.4)]),
            walker(1, [(5.5, 0.2), (7.0, 0.5)]),
            walker(2, [(2.0, -2.0), (6.0, 2.5)]),
            walker(3, [(1.0, 1.0), (2.0, 1.0)], leave=0.5),
            walker(4, [(30.0, 0.0), (31.0, 0.0)]),
        ]
    )


def _scene() -> tuple[Antennas, Antennas, Walls]:
    tx = Antennas(
        position=np.array([[0.0, 0.0, 1.2]]),
        boresight=np.array([0.05]),
        beamwidth=np.array([1.75]),
    )
    rx = Antennas(
        position=np.array([[0.0, 0.3, 1.1], [0.0, -0.3, 1.3]]),
        boresight=np.array([0.0, -0.1]),
        beamwidth=np.array([1.75, 2 * np.pi]),
    )
    walls = Walls(
        start=np.array([[4.0, -5.0], [-1.0, 3.0]]),
        end=np.array([[4.0, 5.0], [9.0, 3.0]]),
        height=np.array([3.0, 1.0]),  # the second one is low: legs to the head pass over it
        reflection=np.array([-0.5, -0.5]),
        transmission=np.array([0.4, 0.7]),
        excess=np.array([0.2, 0.1]),
    )
    return tx, rx, walls


@pytest.mark.parametrize("people_range", [np.inf, 20.0])
def test_body_echo_paths_match_scatterers_and_scatter_paths(people_range: float) -> None:
    rng = np.random.default_rng(5)
    crowd = _crowd(rng)
    tx, rx, walls = _scene()
    ant = np.concatenate([tx.position, rx.position])
    walkers = np.arange(len(crowd.walkers))
    points = np.arange(crowd.n_points)
    crossed = blocked = 0
    for t in np.linspace(0.0, 6.0, 25):
        scale = -rng.rayleigh(np.sqrt(0.5), crowd.n_points)
        # Reference: the numpy body points, far people left out, scatter_paths.
        body = crowd.scatterers(float(t))
        keep = np.hypot(*(body.centres - tx.position[0, :2]).T)[body.owner] <= people_range
        d_ref, a_ref = scatter_paths(
            tx,
            rx,
            body.points[keep],
            body.rcs[keep],
            walls,
            normals=body.normals[keep],
            owner=body.owner[keep],
            blockers=body.centres,
            blocker_radius=body.radius,
            shadow_db=SHADOW_DB,
        )
        a_ref = a_ref * scale[body.index[keep]]
        delays = np.full((2, points.size), np.nan)
        amps = np.full((2, points.size), np.nan)
        count = body_echo_paths(
            float(t),
            crowd.state(float(t), walkers),
            points,
            crowd.point_person,
            crowd.body_point,
            crowd.body_normal,
            crowd.gait_phase,
            crowd.point_height,
            crowd.point_rcs,
            scale,
            crowd.gait_amplitude,
            crowd.breathing_amplitude,
            crowd.radius,
            people_range,
            ant,
            np.concatenate([tx.boresight, rx.boresight]),
            np.concatenate([tx.beamwidth, rx.beamwidth]),
            wall_side(ant, walls),
            walls.start,
            walls.end,
            walls.height,
            walls.transmission,
            walls.excess,
            SHADOW_DB,
            delays,
            amps,
        )
        assert count == a_ref.shape[1]
        np.testing.assert_allclose(delays[:, :count], d_ref, rtol=1e-13, atol=0)
        np.testing.assert_allclose(amps[:, :count], a_ref, rtol=1e-11, atol=0)
        # Paths through a wall (delay beyond the geometric one) and paths shadowed by
        # another body (18 dB below the same path without the other people).
        pts = body.points[keep]
        geometric = (
            np.linalg.norm(pts - tx.position[0], axis=1)
            + np.linalg.norm(pts[None] - rx.position[:, None], axis=2)
        ) / C
        crossed += int(np.sum(d_ref > geometric + 1e-12))
        _, alone = scatter_paths(
            tx, rx, pts, body.rcs[keep], walls, normals=body.normals[keep], shadow_db=SHADOW_DB
        )
        blocked += int(np.sum(np.abs(a_ref) < 0.2 * np.abs(alone * scale[body.index[keep]])))
    assert crossed > 0 and blocked > 0  # the scene exercised walls and shadowing
