"""Simulated node-to-node RTToA ranging: mobile nodes on tracks, anchors, links through walls.

Pure numpy (time ``t`` is an argument). Each link between a mobile node and an anchor is

- a direct path of length ``d`` from the scenario geometry, attenuated and delayed by every
  wall it crosses (the material's one-way transmission loss and the excess path
  ``thickness (sqrt(eps_r) - 1)``, :func:`sim_nodes.channel.geometry.wall_crossings`): LOS, or
  NLOS with an obstructed direct path;
- the specular first-order reflections of the scene's surfaces: each ``[[walls]]`` wall and
  each edge of ``[room]``'s outline by
  the image method (:func:`sim_nodes.channel.paths.image_paths`, order 1), the floor (z = 0,
  or ``[room]``'s floor) and, when ``[room]`` gives one, the ceiling, each with its
  material's signed normal-incidence reflection factor (angle-independent, as in the
  image-method channel) and the transmission of the walls its legs cross;
- dense multipath, an 802.15.4a realization (:mod:`sim_nodes.channel.stochastic`) at the
  unobstructed free-space level (it reaches the receiver around the walls), redrawn every
  round while the node moves and every ``coherence_time`` while it stands still. It starts
  at the earliest specular reflection of the scene (``onset`` of
  :func:`~sim_nodes.channel.stochastic.draw_channel`), never before the direct path.

Why the dense multipath starts there: a path via any point of a plane surface is at least
as long as the specular path of that plane (the unfolded image path is a straight line), so
no energy scattered or reflected by the scene's surfaces arrives earlier; the bound is taken
over the infinite planes (a lower bound for finite walls), for walls only when both ends of
the link are on the same side, and over the free vertical edges of the walls whose line
separates the ends without blocking the link (energy scattered by an edge beside the line
of sight). The edges of a wall the link passes through are not bounded: that multipath
is delayed with the obstructed direct path, as before. The 802.15.4a model alone starts
the rays at the direct path (the first within 0.67 ns, 15 % within 0.1 ns): a ray 0.1 ns
late is a scatterer within the first Fresnel zone of the link, which would obstruct the
direct path rather than add an echo, and the scenarios place nothing there. In lab_los
the earliest reflection, the floor, is 1.5-4 ns after the direct path.

Each round of the ``[ranging]`` scheme renders one impulse response per message in the
receiver's window (sample 0 a random few ns before the first path: preamble sync), and the
radios' timestamps on clocks with random offsets and drifts (``clock_ppm``). The node agent's
:class:`~node_agent.dsp.rttoa.RoundTripRanger` turns them into a range.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from node_agent.dsp.geometry import RadarParams
from node_agent.dsp.rttoa import RoundTrip
from protocol.units import C
from sim_nodes.channel.geometry import (
    Walls,
    mirror,
    wall_crossings,
    wall_hits,
    wall_side,
)
from sim_nodes.channel.paths import Antennas, image_paths
from sim_nodes.channel.stochastic import (
    OFFICE_LOS,
    RESIDENTIAL_LOS,
    draw_channel,
    render,
)
from sim_nodes.scene import MaterialModel, MobileModel, RangingModel, Scenario

FloatArray = npt.NDArray[np.float64]

ENVIRONMENTS = {"office": OFFICE_LOS, "residential": RESIDENTIAL_LOS}

#: The floor when the scenario names no material: concrete, eps_r 6 (Gamma -0.42).
DEFAULT_FLOOR = MaterialModel(permittivity=6.0)


def _with_outline(walls: Walls, scenario: Scenario) -> Walls:
    """``walls`` and the edges of ``[room]``'s outline (reflectors and obstacles of the
    ranging link like any wall, from the floor to the room's top)."""
    room = scenario.room
    if room is None:
        return walls
    mat = scenario.materials[room.material]
    xy = np.asarray(room.outline, float)
    k = xy.shape[0] - 1
    extra = Walls(
        start=xy[:-1],
        end=xy[1:],
        height=np.full(k, room.top),
        reflection=np.full(k, mat.gamma()),
        transmission=np.full(k, mat.transmission()),
        excess=np.full(k, room.thickness * (math.sqrt(mat.permittivity) - 1.0)),
    )
    if walls.count == 0:
        return extra
    excess = walls.excess if walls.excess is not None else np.zeros(walls.count)
    return Walls(
        start=np.concatenate([walls.start, extra.start]),
        end=np.concatenate([walls.end, extra.end]),
        height=np.concatenate([walls.height, extra.height]),
        reflection=np.concatenate([walls.reflection, extra.reflection]),
        transmission=np.concatenate([walls.transmission, extra.transmission]),
        excess=np.concatenate([excess, extra.excess]),
    )


def track_position(mobile: MobileModel, t: float) -> tuple[FloatArray, float, bool]:
    """Position (x, y, z), heading (rad) and whether the node is moving at time ``t``.

    The node goes round its closed track at ``speed``, pausing ``pause`` s at each corner.
    """
    corners = np.asarray(mobile.track, float)
    z = mobile.height
    if corners.shape[0] == 1 or mobile.speed <= 0.0:
        return np.array([*corners[0], z]), 0.0, False
    nxt = np.roll(corners, -1, axis=0)
    seg = np.linalg.norm(nxt - corners, axis=1)
    legs = mobile.pause + seg / mobile.speed
    tau = t % float(legs.sum())
    i = int(np.searchsorted(np.cumsum(legs), tau, side="right"))
    i = min(i, corners.shape[0] - 1)
    tau -= float(np.sum(legs[:i]))
    heading = math.atan2(*(nxt[i] - corners[i])[::-1])
    if tau < mobile.pause:
        return np.array([*corners[i], z]), heading, False
    frac = min((tau - mobile.pause) * mobile.speed / max(seg[i], 1e-12), 1.0)
    return np.array([*(corners[i] + frac * (nxt[i] - corners[i])), z]), heading, True


@dataclass(frozen=True, slots=True, kw_only=True, eq=False)
class LinkState:
    """Geometry of one link at one instant: distance (m), one-way amplitude transmission
    and excess path length (m) of the walls the direct path crosses."""

    distance: float
    transmission: float
    excess: float

    @property
    def los(self) -> bool:
        return self.transmission >= 1.0 and self.excess == 0.0


@dataclass(frozen=True, slots=True, kw_only=True, eq=False)
class Reflections:
    """The specular first-order reflections of one link.

    ``delays`` (ns) count from the geometric direct-path arrival ``d / c`` (they include
    the excess of the walls a leg crosses), ``amplitudes`` are relative to an unobstructed
    direct path (``Gamma T d / L``, L the unfolded length), ``onset`` (ns) is the earliest
    delay at which any reflection or scattering off the scene's surfaces can arrive (over
    the infinite planes of the surfaces; see the module docstring).
    """

    delays: FloatArray
    amplitudes: FloatArray
    onset: float


@dataclass(frozen=True, slots=True, kw_only=True, eq=False)
class RangingRound:
    """One simulated ranging round of a link: what the radios measured and the truth.

    ``delays`` (ns, the direct path first) and ``amplitudes`` are the round's paths, and
    ``lead`` (s) the true first-path delay after each window's start (the same in every
    reception of the round), for error budgets and multipath bounds
    (:func:`fusion_center.localization.crlb.multipath_delay_bound`).
    """

    exchange: RoundTrip
    link: LinkState
    ebn0_db: float
    beta: float
    delays: FloatArray | None = None
    amplitudes: npt.NDArray | None = None
    lead: float = float("nan")


class RangingSimulator:
    """Simulates the RTToA rounds of a scenario's ``[[mobiles]]`` against its ``[[anchors]]``.

    Parameters
    ----------
    scenario : Scenario
        With ``[ranging]``, ``[[anchors]]`` and ``[[mobiles]]``.
    walls : Walls
        The scenario's walls (:func:`sim_nodes.network.scenario_walls`).
    seed : int
    """

    def __init__(self, scenario: Scenario, walls: Walls, seed: int) -> None:
        if scenario.ranging is None or not scenario.mobiles:
            raise ValueError(f"{scenario.name}: no [ranging] with [[mobiles]] to simulate")
        self.scenario = scenario
        self.config: RangingModel = scenario.ranging
        cfg = self.config
        self.radar = RadarParams(
            fs=cfg.fs, n=cfg.n, t0=0.0, f_low=cfg.f_low, f_high=cfg.f_high, fc=cfg.fc
        )
        self.walls = _with_outline(walls, scenario)
        self.anchors = {a.id: np.asarray(a.position, float) for a in scenario.anchors}
        self.mobiles = {m.id: m for m in scenario.mobiles}
        self._env = ENVIRONMENTS[cfg.environment]
        ss = np.random.SeedSequence(seed)
        ids = [*self.mobiles, *self.anchors]
        children = ss.spawn(len(ids) + 1)
        clock_rng = np.random.default_rng(children[0])
        # each node's free-running clock: local = (1 + drift) * t + offset
        self.clocks = {
            nid: (clock_rng.uniform(-1, 1) * cfg.clock_ppm * 1e-6, clock_rng.uniform(0, 1e3))
            for nid in ids
        }
        self._rng = {
            nid: np.random.default_rng(c) for nid, c in zip(ids, children[1:], strict=True)
        }
        self._unit_ebn0, self._beta = self._unit_pulse()
        room = scenario.room
        mats = scenario.materials
        floor_mat = cfg.floor_material or (room.floor_material or room.material if room else None)
        # horizontal reflectors: (height, reflection factor)
        planes = [
            (room.floor if room else 0.0, (mats[floor_mat] if floor_mat else DEFAULT_FLOOR).gamma())
        ]
        if room is not None and room.ceiling is not None:
            ceiling_mat = room.ceiling_material or room.material
            planes.append((room.ceiling, mats[ceiling_mat].gamma()))
        self._planes = np.array(planes, float)
        self._multipath: dict[tuple[str, str], tuple[float, FloatArray, npt.NDArray]] = {}

    def link_state(self, position: FloatArray, anchor: str) -> LinkState:
        """Direct-path geometry between ``position`` (x, y, z) and ``anchor``."""
        a = self.anchors[anchor]
        trans, excess = wall_crossings(position[None, :], a[None, :], self.walls)
        return LinkState(
            distance=float(np.linalg.norm(a - position)),
            transmission=float(trans[0]),
            excess=float(excess[0]),
        )

    def reflections(self, position: FloatArray, anchor: str) -> Reflections:
        """Specular first-order reflections between ``position`` (x, y, z) and ``anchor``.

        Walls by the image method (:func:`sim_nodes.channel.paths.image_paths`, order 1:
        a reflection exists only where its point lies on the wall, below its top); floor
        and ceiling as infinite planes, the image mirrored in z,
        :math:`z' = 2 h - z`; every leg attenuated by the walls it crosses.
        """
        a = self.anchors[anchor]
        p = np.asarray(position, float)
        d = float(np.linalg.norm(a - p))
        omni = np.array([2.0 * np.pi])
        delays: list[FloatArray] = []
        amps: list[FloatArray] = []
        bounds = []
        walls = self.walls
        if walls.count:
            tx = Antennas(position=p[None, :], boresight=np.zeros(1), beamwidth=omni)
            rx = Antennas(position=a[None, :], boresight=np.zeros(1), beamwidth=omni)
            tau, amp = image_paths(tx, rx, walls, max_order=1)
            valid = amp[0, 1:] != 0.0
            delays.append(tau[0, 1:][valid] * 1e9 - d / C * 1e9)
            amps.append(amp[0, 1:][valid] * d)
            # onset bound: the infinite plane of every wall with both ends on one side
            side = wall_side(np.stack([p, a]), walls)
            same = side[0] * side[1] > 0.0
            img = mirror(p[None, :], walls.start[same], walls.end[same])
            bounds.append(np.linalg.norm(img - a, axis=-1) - d)
            # a wall whose line separates the ends without blocking the link (it ends
            # beside it: a door jamb, a partition's end) scatters from its free vertical
            # edges; the shortest path via an edge, unfolded about it, bounds that energy
            crossed = wall_hits(p[None, :], a[None, :], walls)[0]
            beside = (side[0] * side[1] < 0.0) & ~crossed
            if beside.any():
                edges = np.concatenate([walls.start[beside], walls.end[beside]])
                reach = np.linalg.norm(edges - p[:2], axis=-1) + np.linalg.norm(
                    edges - a[:2], axis=-1
                )
                bounds.append(np.hypot(reach, a[2] - p[2]) - d)
        # floor and ceiling reflect only when both ends are on their room side
        h, gamma = self._planes.T
        same = (p[2] - h) * (a[2] - h) > 0.0
        h, gamma = h[same], gamma[same]
        img = np.repeat(p[None, :], h.size, axis=0)
        img[:, 2] = 2.0 * h - p[2]
        length = np.linalg.norm(a - img, axis=-1)
        u = (h - img[:, 2]) / (a[2] - img[:, 2])
        point = img + u[:, None] * (a - img)
        t1, e1 = wall_crossings(np.repeat(p[None, :], h.size, axis=0), point, walls)
        t2, e2 = wall_crossings(point, np.repeat(a[None, :], h.size, axis=0), walls)
        delays.append((length + e1 + e2 - d) / C * 1e9)
        amps.append(gamma * t1 * t2 * d / length)
        bounds.append(length - d)
        bound = np.concatenate(bounds)
        # no surface on the link's side: nothing bounds the multipath (802.15.4a as it is)
        onset = float(np.min(bound)) / C * 1e9 if bound.size else 0.0
        return Reflections(
            delays=np.concatenate(delays), amplitudes=np.concatenate(amps), onset=max(onset, 0.0)
        )

    def _paths(
        self,
        mobile: str,
        anchor: str,
        t: float,
        moving: bool,
        link: LinkState,
        position: FloatArray,
    ) -> tuple[FloatArray, npt.NDArray]:
        rng = self._rng[mobile]
        key = (mobile, anchor)
        refl = self.reflections(position, anchor)
        direct = link.excess / C * 1e9  # ns after d / c: slower inside the walls
        cached = self._multipath.get(key)
        if moving or cached is None or t - cached[0] >= self.config.coherence_time:
            # the dense multipath starts at the earliest reflection the geometry allows,
            # and never before the (possibly delayed) direct path
            delays, amps = draw_channel(
                self._env,
                rng,
                max_delay=self.config.n / self.config.fs * 1e9,
                onset=max(refl.onset, direct),
            )
            cached = (t, delays, amps)
            self._multipath[key] = cached
        _, delays, amps = cached
        # the direct path: through the walls (attenuated, slower inside them); the
        # dense multipath goes round the walls (not attenuated by them)
        delays = np.concatenate([[direct], refl.delays, delays[1:]])
        amps = np.concatenate(
            [[abs(amps[0]) * link.transmission], refl.amplitudes.astype(complex), amps[1:]]
        )
        spread = self.config.reference_distance / max(link.distance, 0.1)
        return delays, amps * spread

    def _receptions(
        self, delays: FloatArray, amps: npt.NDArray, count: int, rng: np.random.Generator
    ) -> tuple[npt.NDArray, float]:
        """``count`` receive windows of one round (the channel does not change within a
        round's milliseconds; the noise does): impulse responses (count, n) and the window
        start before the geometric arrival, s (preamble sync a random 20-30 % into the window)."""
        cfg = self.config
        lead = rng.uniform(0.2, 0.3) * cfg.n
        clean = render(
            delays,
            amps,
            fs=cfg.fs,
            n=cfg.n,
            f_low=cfg.f_low,
            f_high=cfg.f_high,
            fc=cfg.fc,
            first_index=lead,
            snr_db=300.0,
            rng=rng,
        )
        sigma = 10.0 ** (-cfg.snr_db / 20.0)
        if cfg.fc > 0.0:
            noise = rng.standard_normal((count, cfg.n)) + 1j * rng.standard_normal((count, cfg.n))
            h = (clean + sigma * noise).astype(np.complex64)
        else:
            h = (clean + sigma * rng.standard_normal((count, cfg.n))).astype(np.float32)
        return h, lead / cfg.fs

    def _unit_pulse(self) -> tuple[float, float]:
        """E/N0 (dB) and effective RMS bandwidth (Hz) of the direct pulse alone, from its
        samples, for the Cramér-Rao bound :math:`\\sigma_\\tau^2 \\ge 1 / ((2 \\pi
        \\beta)^2 \\, 2 E / N_0)` of :func:`fusion_center.localization.crlb.range_crlb`.

        :math:`E/N_0 = \\sum |s_k|^2 / (2 \\sigma^2)` (``N0`` per real dimension as below).
        :math:`\\beta` is such that the bound equals the mean, over the sampling phase of
        the window (drawn at random every round), of the delay variance bound of the
        sampled pulse with unknown amplitude (and carrier phase, complex baseband): the
        inverse of the delay's equivalent Fisher information, from the Jacobian of the
        samples with respect to delay and amplitude (white noise of :math:`\\sigma` per
        sample and component). The derivative is that of the samples with respect to the
        delay (a central difference over a thousandth of a sample): on a pulse one or two
        samples wide a difference between neighbouring samples would misjudge the slope,
        and the information depends on where the samples fall on the pulse (on the 7 GHz
        radar by a factor of several), hence the mean over the phase: the RMS of the bound
        over many rounds.
        """
        cfg = self.config

        def pulse(first: float) -> npt.NDArray[np.complex128]:
            return render(
                np.zeros(1),
                np.ones(1, complex),
                fs=cfg.fs,
                n=cfg.n,
                f_low=cfg.f_low,
                f_high=cfg.f_high,
                fc=cfg.fc,
                first_index=first,
                snr_db=300.0,
                rng=np.random.default_rng(0),
            ).astype(np.complex128)

        eps = 1e-3  # samples
        energy, var = [], []
        for phase in np.arange(16) / 16.0:
            first = cfg.n / 2 + phase
            s = pulse(first)
            ds = (pulse(first + eps) - pulse(first - eps)) / (2.0 * eps / cfg.fs)
            cols = [ds, s, 1j * s] if cfg.fc > 0.0 else [ds.real, s.real]
            jac = np.stack([np.concatenate([c.real, c.imag]) for c in cols], axis=1)
            var.append(float(np.linalg.inv(jac.T @ jac)[0, 0]))  # per unit noise variance
            energy.append(float(np.sum(np.abs(s) ** 2)))
        sigma = 10.0 ** (-cfg.snr_db / 20.0)
        # complex noise has sigma per component: twice the real noise power per sample
        n0 = 2.0 * sigma**2 * (2.0 if cfg.fc > 0.0 else 1.0)
        ebn0 = float(np.mean(energy)) / n0
        mean_var = float(np.mean(var)) * sigma**2  # s², unit amplitude
        beta = 1.0 / (2.0 * math.pi * math.sqrt(mean_var * 2.0 * ebn0))
        return ebn0, beta

    def round(self, mobile: str, anchor: str, t: float) -> RangingRound:
        """One RTToA round between ``mobile`` (A, initiator) and ``anchor`` (B) at time t."""
        cfg = self.config
        position, _, moving = track_position(self.mobiles[mobile], t)
        link = self.link_state(position, anchor)
        delays, amps = self._paths(mobile, anchor, t, moving, link, position)
        rng = self._rng[mobile]
        tof = link.distance / C
        drift_a, off_a = self.clocks[mobile]
        drift_b, off_b = self.clocks[anchor]

        def local_a(x: float) -> float:
            return (1.0 + drift_a) * x + off_a

        def local_b(x: float) -> float:
            return (1.0 + drift_b) * x + off_b

        n_msg = 3 if cfg.scheme == "ds" else 2
        h, lead = self._receptions(delays, amps, n_msg, rng)
        tx_true = np.zeros(n_msg)
        tx_local = np.zeros(n_msg)
        win = np.zeros(n_msg)
        tx_true[0] = t
        for k in range(n_msg):
            # messages alternate A -> B, B -> A, A -> B
            sender, receiver = (local_a, local_b) if k % 2 == 0 else (local_b, local_a)
            arrive = tx_true[k] + tof
            tx_local[k] = sender(tx_true[k])
            win[k] = receiver(arrive - lead)
            if k + 1 < n_msg:
                # the replier sends reply_delay after its window start on its own clock
                drift_r = drift_b if k % 2 == 0 else drift_a
                tx_true[k + 1] = arrive - lead + cfg.reply_delay / (1.0 + drift_r)
        ebn0 = self._unit_ebn0 * abs(complex(amps[0])) ** 2
        return RangingRound(
            exchange=RoundTrip(tx_times=tx_local, window_starts=win, h=h),
            link=link,
            ebn0_db=10.0 * math.log10(max(ebn0, 1e-30)),
            beta=self._beta,
            delays=delays,
            amplitudes=amps,
            lead=lead,
        )
