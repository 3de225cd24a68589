"""Compiled (numba) kernel of the simulator's per-acquisition people echoes.

Per acquisition a node synthesises the single-bounce paths Tx -> body point -> Rx of a dozen
body points (:meth:`sim_nodes.network.SimNetwork.people_spectrum`). In numpy that is some
seventy small array calls (body points, antenna gains, wall crossings, shadowing), each a few
microseconds on arrays of a dozen elements: 60 % of the simulator's CPU time. This kernel
does the same arithmetic in one compiled loop over the points. It is a pure function of
arrays (no I/O, no clocks), compiled on first use with ``cache=True`` so that later
processes load the machine code from numba's cache.

The numpy functions it replaces stay the reference: :meth:`sim_nodes.channel.Crowd.scatterers`
and :func:`sim_nodes.channel.scatter_paths` (``SimNetwork(reference=True)``);
``tests/unit/sim/test_kernels.py`` compares them.
"""

from __future__ import annotations

import math

import numba
import numpy as np

from sim_nodes.channel.people import STEP_LENGTH
from sim_nodes.radar import C

#: Columns of the per-person state rows of :func:`body_echo_paths`.
PRESENT, PX, PY, HEADING, SPEED, BREATH = range(6)
#: Back-lobe floor of the antenna pattern, dB (``geometry.antenna_gain``'s default).
GAIN_FLOOR_DB = -25.0
_EPS = 1e-9
_LN10_20 = math.log(10.0) / 20.0


@numba.njit(cache=True)
def _gain(dx: float, dy: float, boresight: float, beamwidth: float) -> float:
    # geometry.antenna_gain for one direction: Gaussian beam in dB, clipped at the floor.
    if beamwidth >= 2 * math.pi:
        return 1.0
    off = math.atan2(dy, dx) - boresight + math.pi
    off = off - 2 * math.pi * math.floor(off / (2 * math.pi)) - math.pi
    g = -3.0 * (2 * off / beamwidth) ** 2
    return math.exp(max(g, GAIN_FLOOR_DB) * _LN10_20)


@numba.njit(cache=True)
def body_echo_paths(
    t: float,
    state: np.ndarray,
    points: np.ndarray,
    point_owner: np.ndarray,
    body_point: np.ndarray,
    body_normal: np.ndarray,
    gait_phase: np.ndarray,
    height: np.ndarray,
    weight: np.ndarray,
    amp_scale: np.ndarray,
    gait_amplitude: float,
    breathing_amplitude: float,
    radius: np.ndarray,
    people_range: float,
    ant_pos: np.ndarray,
    ant_boresight: np.ndarray,
    ant_beamwidth: np.ndarray,
    ant_side: np.ndarray,
    wall_start: np.ndarray,
    wall_end: np.ndarray,
    wall_height: np.ndarray,
    wall_transmission: np.ndarray,
    wall_excess: np.ndarray,
    shadow_db: float,
    delays: np.ndarray,
    amps: np.ndarray,
) -> int:
    """Delays and amplitudes of the people's single-bounce paths at one node.

    The body points of :meth:`sim_nodes.channel.Crowd.scatterers` (ellipse point, breathing
    along the body normal, gait along the heading, rotated to the heading) and, for each
    point whose person is present and within ``people_range`` of the transmitter (x, y), the
    path of :func:`sim_nodes.channel.scatter_paths`:

    .. math:: a = s_q \\sqrt{\\sigma_q / 4\\pi}\\, F_{tx} F_{rx}\\, S_1 S_2\\, T_1 T_2 / (d_1 d_2),
              \\quad \\tau = (d_1 + d_2 + \\Delta_1 + \\Delta_2) / c

    (antenna gains ``F``, shadowing ``S`` by the other present bodies and by the point's own
    body, through-wall factors ``T`` and excess lengths ``Delta``), times the caller's
    per-point factor ``s_q`` (sign of the body reflection and amplitude fluctuation).

    Parameters
    ----------
    t : float
        Time, s (gait and breathing phases).
    state : ndarray, float64, shape (M, 6)
        Per person: present (1/0), x, y (m), heading (rad), speed (m/s), sine of the
        breathing phase; the columns ``PRESENT ... BREATH``.
    points : ndarray, int64, shape (Q,)
        Body points to consider, ascending (the path order).
    point_owner : ndarray, int64, shape (Q,)
        Row of ``state`` each of those points belongs to.
    body_point, body_normal : ndarray, shape (P, 2)
        Body-frame ellipse point and outward unit normal of every body point of the crowd.
    gait_phase, height, weight : ndarray, shape (P,)
        Gait phase (rad), height above the floor (m) and radar cross-section (m^2) of every
        body point.
    amp_scale : ndarray, shape (P,)
        Factor ``s_q`` of every body point.
    gait_amplitude, breathing_amplitude : float
        m (see :class:`sim_nodes.channel.Crowd`).
    radius : ndarray, shape (M,)
        Body radii for shadowing, m.
    people_range : float
        Points of people farther than this from the transmitter are left out, m.
    ant_pos : ndarray, shape (A, 3)
        Transmitter (row 0) and receivers, world, m.
    ant_boresight, ant_beamwidth : ndarray, shape (A,)
        rad.
    ant_side : ndarray, shape (A, W)
        ``geometry.wall_side`` of the antennas.
    wall_start, wall_end : ndarray, shape (W, 2)
    wall_height, wall_transmission, wall_excess : ndarray, shape (W,)
        The walls that can matter (see ``SimNetwork._local_view``).
    shadow_db : float
        Attenuation of a leg through a body, dB.
    delays, amps : ndarray, float64, shape (A - 1, >= Q)
        Output buffers: paths ``0 .. count - 1`` of each receiver are written.

    Returns
    -------
    int
        ``count``, the number of paths written per receiver.
    """
    n_ant = ant_pos.shape[0]
    n_walls = wall_start.shape[0]
    n_people = state.shape[0]
    tx_x, tx_y = ant_pos[0, 0], ant_pos[0, 1]
    leg_db_body = -shadow_db / 20.0
    leg_db_self = -shadow_db / 40.0
    factor = np.empty(n_ant)
    dist = np.empty(n_ant)
    excess = np.empty(n_ant)
    count = 0
    for j in range(points.shape[0]):
        q = points[j]
        m = point_owner[j]
        if state[m, PRESENT] == 0.0:
            continue
        cx, cy = state[m, PX], state[m, PY]
        if math.hypot(cx - tx_x, cy - tx_y) > people_range:
            continue
        v = state[m, SPEED]
        gait = (
            gait_amplitude
            * (v / 1.2)
            * math.sin(2 * math.pi * (v / STEP_LENGTH) * t + gait_phase[q])
        )
        nbx, nby = body_normal[q, 0], body_normal[q, 1]
        breath = breathing_amplitude * state[m, BREATH]
        lx = body_point[q, 0] + breath * nbx + gait
        ly = body_point[q, 1] + breath * nby
        c, s = math.cos(state[m, HEADING]), math.sin(state[m, HEADING])
        px = cx + c * lx - s * ly
        py = cy + s * lx + c * ly
        pz = height[q]
        nx = c * nbx - s * nby
        ny = s * nbx + c * nby
        for a in range(n_ant):
            vx = px - ant_pos[a, 0]
            vy = py - ant_pos[a, 1]
            vz = pz - ant_pos[a, 2]
            dist[a] = math.sqrt(vx * vx + vy * vy + vz * vz)
            f = _gain(vx, vy, ant_boresight[a], ant_beamwidth[a])
            e = 0.0
            for w in range(n_walls):
                ex = wall_end[w, 0] - wall_start[w, 0]
                ey = wall_end[w, 1] - wall_start[w, 1]
                norm = math.hypot(ex, ey)
                side = (ex * (py - wall_start[w, 1]) - ey * (px - wall_start[w, 0])) / norm
                if ant_side[a, w] * side >= 0:
                    continue  # both ends on one side of the wall's line: no crossing
                # geometry.segment_intersection / wall_crossings for the leg antenna -> point
                den = vx * ey - vy * ex
                if abs(den) < 1e-15:
                    continue
                wx = wall_start[w, 0] - ant_pos[a, 0]
                wy = wall_start[w, 1] - ant_pos[a, 1]
                u = (wx * ey - wy * ex) / den
                sw = (wx * vy - wy * vx) / den
                z = ant_pos[a, 2] + u * vz
                if _EPS < u < 1 - _EPS and 0 <= sw <= 1 and z <= wall_height[w]:
                    f *= wall_transmission[w]
                    e += wall_excess[w]
            blocked = 0
            rr = max(vx * vx + vy * vy, 1e-12)
            for b in range(n_people):
                if b == m or state[b, PRESENT] == 0.0:
                    continue
                bx = state[b, PX] - ant_pos[a, 0]
                by = state[b, PY] - ant_pos[a, 1]
                dot = vx * bx + vy * by
                if 0 < dot < rr and bx * bx + by * by - dot * dot / rr < radius[b] ** 2:
                    blocked += 1
            if blocked:
                f *= 10.0 ** (leg_db_body * blocked)
            horiz = max(math.sqrt(vx * vx + vy * vy), 1e-9)
            cos = -(nx * vx + ny * vy) / horiz
            f *= 10.0 ** (leg_db_self * (1 - cos))
            factor[a] = f
            excess[a] = e
        base = amp_scale[q] * math.sqrt(abs(weight[q]) / (4 * math.pi)) * factor[0]
        for r in range(1, n_ant):
            amps[r - 1, count] = base * factor[r] / (dist[0] * dist[r])
            delays[r - 1, count] = (dist[0] + dist[r] + excess[0] + excess[r]) / C
        count += 1
    return count
