"""Simulated node-to-node RTToA ranging: mobile nodes on tracks, anchors, links through walls.

Pure numpy (time ``t`` is an argument). Each link between a mobile node and an anchor is

- a direct path of length ``d`` from the scenario geometry, attenuated and delayed by every
  wall it crosses (the material's one-way transmission loss and the excess path
  ``thickness (sqrt(eps_r) - 1)``, :func:`sim_nodes.channel.geometry.wall_crossings`): LOS, or
  NLOS with an obstructed direct path;
- dense multipath after it, an 802.15.4a realization (:mod:`sim_nodes.channel.stochastic`)
  at the unobstructed free-space level (it reaches the receiver around the walls), redrawn
  every round while the node moves and every ``coherence_time`` while it stands still.

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
from sim_nodes.channel.geometry import Walls, wall_crossings
from sim_nodes.channel.stochastic import (
    OFFICE_LOS,
    RESIDENTIAL_LOS,
    draw_channel,
    render,
)
from sim_nodes.scene import MobileModel, RangingModel, Scenario

FloatArray = npt.NDArray[np.float64]

ENVIRONMENTS = {"office": OFFICE_LOS, "residential": RESIDENTIAL_LOS}


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
        self.walls = walls
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

    def _paths(
        self, mobile: str, anchor: str, t: float, moving: bool, link: LinkState
    ) -> tuple[FloatArray, npt.NDArray]:
        rng = self._rng[mobile]
        key = (mobile, anchor)
        cached = self._multipath.get(key)
        if moving or cached is None or t - cached[0] >= self.config.coherence_time:
            delays, amps = draw_channel(
                self._env, rng, max_delay=self.config.n / self.config.fs * 1e9
            )
            cached = (t, delays, amps)
            self._multipath[key] = cached
        _, delays, amps = cached
        delays = delays.copy()
        amps = amps.copy()
        # the direct path: through the walls, slower inside them; the 802.15.4a multipath
        # delays are relative to the direct path (its excess delays them too), but it goes
        # round the walls (not attenuated by them)
        amps[0] = abs(amps[0]) * link.transmission
        delays = delays + link.excess / C * 1e9
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
        delays, amps = self._paths(mobile, anchor, t, moving, link)
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
