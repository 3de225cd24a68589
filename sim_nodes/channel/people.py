"""People as extended, moving, fluctuating scatterers.

A person walks a polyline of waypoints at constant speed, back and forth (``bounce``) or
once, between ``enter`` and ``leave``. The body is K point scatterers on an ellipse around
the walking position (semi-axes ``0.15 m`` along the walking direction, ``0.22 m`` across:
a 0.3 m x 0.45 m torso), oriented with the heading; the points move with breathing
(mm along the body normal at 0.2-0.3 Hz) and gait (cm along the heading at the step rate).
Each point's amplitude fluctuates (AR(1) complex Gaussian, Rayleigh magnitude), see
:class:`Fluctuation`. Pure numpy: time is an argument.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

#: Semi-axes of the body ellipse along / across the heading, m.
BODY_SEMI_AXES = (0.15, 0.22)
#: Stride length per step, m: the gait frequency is speed / STEP_LENGTH.
STEP_LENGTH = 0.7


@dataclass(frozen=True, slots=True, kw_only=True)
class Walker:
    """One person's trajectory and body (static description).

    Attributes
    ----------
    id : int
    waypoints : ndarray, float64, shape (J, 2)
        World x, y, m; J >= 2.
    speed : float
        Walking speed, m/s.
    bounce : bool
        Walk back and forth (else once, then stand at the last waypoint).
    enter, leave : float
        Presence interval ``enter <= t < leave``, s (``leave`` may be inf).
    radius : float
        Body radius for shadowing, m.
    rcs : float
        Total radar cross-section, m^2, shared among the points by ``weights``.
    height : float
        Height of the body scatterers' centre, m.
    angles : ndarray, shape (K,)
        Positions of the points on the body ellipse, rad from the heading.
    weights : ndarray, shape (K,)
        Share of the RCS of each point (sums to 1).
    dz : ndarray, shape (K,)
        Height offsets of the points, m.
    gait_phase : ndarray, shape (K,)
        Phase of each point's gait swing, rad.
    breathing_phase : float
        rad.
    breathing_rate : float
        Hz.
    """

    id: int
    waypoints: npt.NDArray[np.float64]
    speed: float
    bounce: bool
    enter: float
    leave: float
    radius: float
    rcs: float
    height: float
    angles: npt.NDArray[np.float64]
    weights: npt.NDArray[np.float64]
    dz: npt.NDArray[np.float64]
    gait_phase: npt.NDArray[np.float64]
    breathing_phase: float
    breathing_rate: float
    _polyline: tuple[list[list[float]], list[float], float] = field(
        init=False, repr=False, compare=False
    )

    def __post_init__(self) -> None:
        wp = np.asarray(self.waypoints, float).tolist()
        seg_len = [math.dist(a, b) for a, b in itertools.pairwise(wp)]
        object.__setattr__(self, "_polyline", (wp, seg_len, sum(seg_len)))

    def min_distance(self, point: npt.ArrayLike) -> float:
        """Smallest distance (m, in x, y) of the walked polyline from ``point``."""
        p = np.asarray(point, float)[:2]
        a, b = self.waypoints[:-1], self.waypoints[1:]
        r = b - a
        u = np.clip(np.sum((p - a) * r, axis=1) / np.maximum(np.sum(r * r, axis=1), 1e-30), 0, 1)
        return float(np.min(np.hypot(*(a + u[:, None] * r - p).T)))

    def present(self, t: float) -> bool:
        """Whether the person is in the scene at time t, s."""
        return self.enter <= t < self.leave

    def kinematics(self, t: float) -> tuple[np.ndarray, np.ndarray, float]:
        """Position, velocity and heading at time t.

        With ``L`` the polyline length and ``s = v (t - enter)`` the walked distance, the
        arc-length position is ``s mod 2L`` folded back on the way home (``bounce``) or
        ``min(s, L)`` (once).

        Returns
        -------
        position : ndarray, shape (2,), m
        velocity : ndarray, shape (2,), m/s
        heading : float, rad (direction of motion; kept when standing)
        """
        x, y, vx, vy, heading = self.motion(t)
        return np.array([x, y]), np.array([vx, vy]), heading

    def motion(self, t: float) -> tuple[float, float, float, float, float]:
        """:meth:`kinematics` as plain floats ``(x, y, vx, vy, heading)``."""
        # Plain floats: a polyline has a handful of vertices and numpy's per-call overhead
        # would dominate (this runs for every acquisition); its segments are measured once.
        wp, seg_len, total = self._polyline
        s = self.speed * max(t - self.enter, 0.0)
        if self.bounce:
            s = s % (2 * total)
            sign, arc, moving = (1.0, s, 1.0) if s <= total else (-1.0, 2 * total - s, 1.0)
        else:
            arc, sign = min(s, total), 1.0
            moving = 1.0 if s < total else 0.0
        i, start = 0, 0.0
        while i < len(seg_len) - 1 and arc > start + seg_len[i]:
            start += seg_len[i]
            i += 1
        ux = (wp[i + 1][0] - wp[i][0]) / seg_len[i]
        uy = (wp[i + 1][1] - wp[i][1]) / seg_len[i]
        return (
            wp[i][0] + (arc - start) * ux,
            wp[i][1] + (arc - start) * uy,
            sign * moving * self.speed * ux,
            sign * moving * self.speed * uy,
            math.atan2(sign * uy, sign * ux),
        )


@dataclass(frozen=True, slots=True, kw_only=True)
class BodyScatterers:
    """Scatterers of all present people at one instant (Q = sum of their points).

    Attributes
    ----------
    points : ndarray, shape (Q, 3)
        World positions, m.
    normals : ndarray, shape (Q, 2)
        Outward body normals, x, y.
    rcs : ndarray, shape (Q,)
        Mean cross-section of each point, m^2.
    owner : ndarray, int, shape (Q,)
        Index into ``centres`` of the person each point belongs to.
    index : ndarray, int, shape (Q,)
        Flat index of the point over all walkers' points (for fluctuation state).
    centres : ndarray, shape (M, 2)
        Body centres of the present people, m.
    radius : ndarray, shape (M,)
        Their body radii, m.
    """

    points: npt.NDArray[np.float64]
    normals: npt.NDArray[np.float64]
    rcs: npt.NDArray[np.float64]
    owner: npt.NDArray[np.int_]
    index: npt.NDArray[np.int_]
    centres: npt.NDArray[np.float64]
    radius: npt.NDArray[np.float64]


class Crowd:
    """All people of a scenario: truth and body scatterers as functions of time.

    Parameters
    ----------
    walkers : sequence of Walker
    breathing_amplitude : float
        Chest displacement amplitude, m.
    gait_amplitude : float
        Swing amplitude of the points along the heading at nominal speed, m.
    """

    def __init__(
        self,
        walkers: list[Walker],
        breathing_amplitude: float = 0.005,
        gait_amplitude: float = 0.05,
    ) -> None:
        self.walkers = list(walkers)
        self.breathing_amplitude = breathing_amplitude
        self.gait_amplitude = gait_amplitude
        counts = [len(w.angles) for w in self.walkers]
        self._offset = np.concatenate([[0], np.cumsum(counts)]).astype(int)
        #: Total number of body points over all walkers.
        self.n_points = int(self._offset[-1])
        cat = np.concatenate if self.walkers else (lambda _x: np.zeros(0))
        self._angles = cat([w.angles for w in self.walkers])
        self._weights = cat([w.weights * w.rcs for w in self.walkers])
        self._dz = cat([w.dz + w.height for w in self.walkers])
        self._gait_phase = cat([w.gait_phase for w in self.walkers])
        self._person = np.repeat(np.arange(len(self.walkers)), counts)
        self._radius = np.array([w.radius for w in self.walkers], float)
        a, b = BODY_SEMI_AXES
        th = self._angles
        # Body-frame points on the ellipse and outward normals of (x/a)^2 + (y/b)^2 = 1.
        self._body_point = np.stack([a * np.cos(th), b * np.sin(th)], axis=1)
        nb = np.stack([np.cos(th) / a, np.sin(th) / b], axis=1)
        self._body_normal = nb / np.maximum(np.linalg.norm(nb, axis=1, keepdims=True), 1e-12)
        # Read-only views of the per-point description for the compiled people echoes
        # (sim_nodes.channel.kernels), shape (n_points, ...), and the per-person radii.
        self.body_point, self.body_normal = self._body_point, self._body_normal
        self.gait_phase, self.point_height = self._gait_phase, self._dz
        self.point_rcs, self.point_person, self.radius = self._weights, self._person, self._radius

    def truth(self, t: float) -> list[dict]:
        """Ground truth ``{id, x, y, vx, vy}`` of the people present at t."""
        out = []
        for w in self.walkers:
            if w.present(t):
                pos, vel, _ = w.kinematics(t)
                out.append(
                    {
                        "id": int(w.id),
                        "x": float(pos[0]),
                        "y": float(pos[1]),
                        "vx": float(vel[0]),
                        "vy": float(vel[1]),
                    }
                )
        return out

    def state(self, t: float, walkers: Iterable[int]) -> npt.NDArray[np.float64]:
        """Per person of ``walkers`` (indices into the crowd) at time t: present (1/0), x, y
        (m), heading (rad), speed (m/s) and the sine of the breathing phase; shape (M, 6),
        zeros for an absent person."""
        # The loop is over a handful of people (kinematics on each polyline); the points
        # themselves are handled as arrays.
        walkers = list(walkers)
        per = np.zeros((len(walkers), 6))
        for row, i in enumerate(walkers):
            w = self.walkers[i]
            if w.present(t):
                x, y, vx, vy, psi = w.motion(t)
                phase = 2 * math.pi * w.breathing_rate * t + w.breathing_phase
                per[row] = (1.0, x, y, psi, math.hypot(vx, vy), math.sin(phase))
        return per

    def scatterers(self, t: float, walkers: npt.NDArray[np.int_] | None = None) -> BodyScatterers:
        """Body scatterers of the present people at time t.

        ``walkers`` (indices into the crowd) limits the result to those people: the others
        are treated as absent (a caller that knows they can never matter, e.g. a node far
        from their whole path, skips their kinematics).

        Point k of a person at ``p`` with heading ``psi`` and speed ``v``:

        .. math::
            q_k = p + R(\\psi) [a \\cos\\theta_k + g_k,\\; b \\sin\\theta_k]
                  + \\beta \\sin(2\\pi f_b t + \\phi) n_k,
            \\quad g_k = A_g (v / 1.2) \\sin(2\\pi (v / 0.7) t + \\phi_k)

        with ``n_k`` the outward ellipse normal (breathing), ``A_g`` the gait amplitude.
        """
        per = np.zeros((len(self.walkers), 6))
        if walkers is None:
            per[:] = self.state(t, range(len(self.walkers)))
        else:
            per[walkers] = self.state(t, walkers.tolist())
        here = per[:, 0] > 0
        sel = np.flatnonzero(here[self._person])
        person = self._person[sel]
        pp = per[person]  # (Q, 6) per-point copy of its person's state
        v = pp[:, 4]
        gait = (
            self.gait_amplitude
            * (v / 1.2)
            * np.sin(2 * np.pi * (v / STEP_LENGTH) * t + self._gait_phase[sel])
        )
        nb = self._body_normal[sel]
        local = self._body_point[sel] + (self.breathing_amplitude * pp[:, 5])[:, None] * nb
        local[:, 0] += gait
        c, s = np.cos(pp[:, 3]), np.sin(pp[:, 3])
        points = np.empty((sel.size, 3))
        points[:, 0] = pp[:, 1] + c * local[:, 0] - s * local[:, 1]
        points[:, 1] = pp[:, 2] + s * local[:, 0] + c * local[:, 1]
        points[:, 2] = self._dz[sel]
        normals = np.stack([c * nb[:, 0] - s * nb[:, 1], s * nb[:, 0] + c * nb[:, 1]], axis=1)
        # Owner as an index into the present people (the blocker list).
        rank = np.cumsum(here) - 1
        return BodyScatterers(
            points=points,
            normals=normals,
            rcs=self._weights[sel],
            owner=rank[person],
            index=sel,
            centres=per[here, 1:3],
            radius=self._radius[here],
        )


def make_walker(
    *,
    person_id: int,
    waypoints: npt.ArrayLike,
    speed: float,
    bounce: bool,
    enter: float,
    leave: float | None,
    radius: float,
    rcs: float,
    height: float,
    n_scatterers: int,
    breathing_rate: float,
    rng: np.random.Generator,
) -> Walker:
    """Build a :class:`Walker` with seeded random body details (point layout, phases)."""
    k = n_scatterers
    angles = 2 * np.pi * (np.arange(k) + rng.uniform(-0.3, 0.3, k)) / k
    weights = rng.uniform(0.5, 1.5, k)
    return Walker(
        id=person_id,
        waypoints=np.asarray(waypoints, float),
        speed=speed,
        bounce=bounce,
        enter=enter,
        leave=np.inf if leave is None else leave,
        radius=radius,
        rcs=rcs,
        height=height,
        angles=angles,
        weights=weights / weights.sum(),
        dz=rng.uniform(-0.3, 0.3, k),
        gait_phase=rng.uniform(0, 2 * np.pi, k),
        breathing_phase=float(rng.uniform(0, 2 * np.pi)),
        breathing_rate=breathing_rate * float(rng.uniform(0.85, 1.15)),
    )


class Fluctuation:
    """Frame-to-frame correlated amplitude fluctuation of body points (one per receiver node).

    AR(1) complex Gaussian per point, unit mean power, correlation time ``tau_c``:

    .. math:: x_{t} = \\rho x_{t'} + \\sqrt{1 - \\rho^2} w,
              \\quad \\rho = \\exp(-|t - t'| / \\tau_c),\\; w \\sim CN(0, 1)

    The amplitude factor is ``|x|`` (Rayleigh, mean square 1).

    Parameters
    ----------
    n_points : int
        Number of body points over all walkers.
    correlation_time : float
        tau_c, s.
    rng : numpy.random.Generator
        The owning node's generator.
    """

    def __init__(self, n_points: int, correlation_time: float, rng: np.random.Generator) -> None:
        self.correlation_time = correlation_time
        self._rng = rng
        self._t: float | None = None
        self._x = self._draw(n_points)

    def _draw(self, n: int) -> np.ndarray:
        z = self._rng.standard_normal((2, n))
        return (z[0] + 1j * z[1]) / np.sqrt(2)

    def step(self, t: float) -> npt.NDArray[np.float64]:
        """Advance to time t and return the amplitude factors ``|x|``, shape (n_points,)."""
        if self._t is not None:
            rho = np.exp(-abs(t - self._t) / self.correlation_time)
            self._x = rho * self._x + np.sqrt(1 - rho**2) * self._draw(self._x.shape[0])
        self._t = t
        return np.abs(self._x)

    def advance(self, t: float) -> None:
        """Advance to time t drawing what :meth:`step` draws, without computing the factors:
        for a node that no body point can ever reach (the generator's stream, and so the
        node's later noise, stays what :meth:`step` leaves; the factors are never used)."""
        if self._t is not None:
            self._rng.standard_normal((2, self._x.shape[0]))
        self._t = t
