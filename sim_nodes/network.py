"""The simulated sensor network: node descriptions, TDMA schedule, acquisitions, truth.

:class:`SimNetwork` is the pure core the simulated driver and the recorder wrap: no
zenoh, no files, no clocks (time ``t`` is an argument). Each bat node's own transmitter
illuminates the scene; its two receivers record

.. math:: h_r = \\mathrm{irfft}(G (C^{static}_r + C^{people}_r(t)) + V_r)

where the static channel is computed once per node and only the people's single-bounce
paths are computed per call. The static channel is the scenario's ``[channel] model``:
``image2d`` (coupling and wall reflections up to order 2, scalar reflection factors) or
``hybrid`` (:mod:`sim_nodes.channel.hybrid`: 3-D ray tracing with Fresnel reflection,
diffraction and the stochastic scatterer clusters, one realization per seed).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from sim_nodes.channel import (
    Antennas,
    Crowd,
    Fluctuation,
    Walls,
    image_paths,
    make_walker,
    scatter_paths,
)
from sim_nodes.channel.antenna import AntennaPattern, HornPattern, OmniPattern
from sim_nodes.channel.geometry import segment_point_distance, wall_side
from sim_nodes.channel.hybrid import HybridChannel
from sim_nodes.channel.kernels import body_echo_paths
from sim_nodes.channel.raytrace import AntennaArray
from sim_nodes.channel.synth import frequency_response
from sim_nodes.propagation import hybrid_channel, table_pattern
from sim_nodes.radar import MSequenceRadar
from sim_nodes.scene import BAT_ANTENNAS, NodeModel, Scenario, ScenarioError, load_scenario

#: Horn 3 dB beamwidth, rad (about 100 degrees).
BAT_BEAMWIDTH = 1.75

#: Sign of a body point's echo: reflection off a high-permittivity body (Gamma < 0).
BODY_REFLECTION_SIGN = -1.0


@dataclass(frozen=True, slots=True, kw_only=True)
class _Node:
    id: str
    pose: tuple[float, float, float, float]
    antennas: dict[str, dict]
    tx: Antennas
    rx: Antennas
    rx_names: tuple[str, ...]


def _build_node(model: NodeModel) -> _Node:
    x, y, z, yaw = model.pose
    antennas = {}
    for name, (pos, is_tx, is_rx) in BAT_ANTENNAS.items():
        ov = model.antennas.get(name)
        antennas[name] = {
            "pos": [float(v) for v in (ov.pos if ov and ov.pos else pos)],
            "tx": is_tx,
            "rx": is_rx,
            "boresight": float(ov.boresight if ov and ov.boresight is not None else 0.0),
            "beamwidth": float(ov.beamwidth if ov and ov.beamwidth else BAT_BEAMWIDTH),
        }
    c, s = np.cos(yaw), np.sin(yaw)

    def world(names: list[str]) -> Antennas:
        pos = np.array([antennas[n]["pos"] for n in names], float)
        xy = np.stack([x + c * pos[:, 0] - s * pos[:, 1], y + s * pos[:, 0] + c * pos[:, 1]], 1)
        return Antennas(
            position=np.concatenate([xy, z + pos[:, 2:3]], axis=1),
            boresight=yaw + np.array([antennas[n]["boresight"] for n in names]),
            beamwidth=np.array([antennas[n]["beamwidth"] for n in names]),
        )

    rx_names = tuple(n for n, a in antennas.items() if a["rx"])
    return _Node(
        id=model.id,
        pose=(float(x), float(y), float(z), float(yaw)),
        antennas=antennas,
        tx=world(["tx"]),
        rx=world(list(rx_names)),
        rx_names=rx_names,
    )


def scenario_walls(scenario: Scenario) -> Walls:
    """The scenario's ``[[walls]]`` with their materials' reflection, one-way transmission and
    excess path length ``thickness (sqrt(eps_r) - 1)``, m."""
    mats = scenario.materials
    walls = scenario.walls
    if not walls:
        return Walls.empty()
    return Walls(
        start=np.array([w.start for w in walls], float),
        end=np.array([w.end for w in walls], float),
        height=np.array([w.height for w in walls], float),
        reflection=np.array([mats[w.material].gamma() for w in walls], float),
        transmission=np.array([mats[w.material].transmission() for w in walls], float),
        excess=np.array(
            [w.thickness * (np.sqrt(mats[w.material].permittivity) - 1) for w in walls]
        ),
    )


#: Bound on how far a body point (ellipse, gait, breathing) and a node's receive antenna
#: lie from the body centre and from the transmitter, m (generous: about 0.3 m and 0.5 m).
BODY_REACH = 1.0


@dataclass(frozen=True, slots=True, kw_only=True)
class _LocalView:
    """Per-node precomputation of :meth:`SimNetwork._local_view`."""

    walkers: npt.NDArray[np.int64]
    walls: Walls
    antenna_side: npt.NDArray[np.float64]
    #: The body points of ``walkers`` (flat crowd indices, ascending) and each one's
    #: position in ``walkers``.
    points: npt.NDArray[np.int64]
    point_owner: npt.NDArray[np.int64]
    #: Tx and Rx antennas stacked (positions, boresights, beam widths), and the walls' excess
    #: lengths (zeros if the walls have none), as the compiled kernel takes them.
    antenna_pos: npt.NDArray[np.float64]
    antenna_boresight: npt.NDArray[np.float64]
    antenna_beamwidth: npt.NDArray[np.float64]
    wall_excess: npt.NDArray[np.float64]
    #: Body radii of ``walkers``, m.
    radius: npt.NDArray[np.float64]


class SimNetwork:
    """A network of simulated static bat-type nodes in a scenario.

    Parameters
    ----------
    scenario : Scenario or str
        A validated scenario, or a shipped name / path for :func:`load_scenario`.
    seed : int
        Master seed. Body details come from one child of ``SeedSequence(seed)``; each node
        (in scenario order) gets its own child generator for noise and amplitude
        fluctuation, so a node's output depends only on the seed and the times at which
        that node was acquired.
    people_range : float
        People whose body centre is farther than this (m, in x, y) from a node's transmitter
        are left out of its acquisitions (default: nobody is). Large buildings use it: the
        echo of a person several rooms away is far below the noise, and leaving it out keeps
        the cost per acquisition independent of the number of people in the building.
    reference : bool
        Synthesise every acquisition in full (all people, all walls, antenna geometry
        recomputed per call) instead of with the per-node precomputation described in
        :meth:`people_spectrum`. Both give the same impulse responses; the full synthesis
        is kept as the reference the tests compare the fast path with.
    window : int or None
        Deliver only the first ``window`` samples of each impulse response (``node_info``
        then says ``radar.n = window``: the radar window PROTOCOL.md allows). The static
        channel's response is then computed once per node in the time domain, the people's
        echoes are added in the time domain (one inverse FFT per acquisition that has any),
        and the thermal noise is drawn for the window only
        (:meth:`MSequenceRadar.window_noise`: the same std and correlation, other
        realisations). None (default): the whole period, as a radar delivers it. A large
        building with a bounded ``people_range`` needs no sample beyond about twice that
        range (``uwbnet scale --ir-window``, docs/capacity.md).
    """

    def __init__(
        self,
        scenario: Scenario | str,
        seed: int,
        *,
        people_range: float = np.inf,
        reference: bool = False,
        window: int | None = None,
    ) -> None:
        if isinstance(scenario, str):
            scenario = load_scenario(scenario)
        if not scenario.nodes:
            raise ScenarioError(
                f"{scenario.name}: no static [[nodes]] to simulate (a [robot] scenario: "
                f"use 'uwbnet channel dataset {scenario.name}')"
            )
        self.scenario = scenario
        self.seed = seed
        self.people_range = float(people_range)
        self.radar = MSequenceRadar(scenario.radar.config())
        ch = scenario.channel
        self.walls = scenario_walls(scenario)
        # Child n + 1 (the channel realization) is new; children 0..n are unchanged by it.
        children = np.random.SeedSequence(seed).spawn(len(scenario.nodes) + 2)
        scene_rng = np.random.default_rng(children[0])
        self.crowd = Crowd(
            [
                make_walker(
                    person_id=p.id,
                    waypoints=p.waypoints,
                    speed=p.speed,
                    bounce=p.mode == "bounce",
                    enter=p.enter,
                    leave=p.leave,
                    radius=p.radius,
                    rcs=p.rcs,
                    height=p.height,
                    n_scatterers=p.n_scatterers,
                    breathing_rate=ch.breathing_rate,
                    rng=scene_rng,
                )
                for p in scenario.people
            ],
            breathing_amplitude=ch.breathing_amplitude,
            gait_amplitude=ch.gait_amplitude,
        )
        self._nodes = {m.id: _build_node(m) for m in scenario.nodes}
        self._local = {
            nid: None if reference else self._local_view(node) for nid, node in self._nodes.items()
        }
        self._rng = {
            nid: np.random.default_rng(child)
            for nid, child in zip(self._nodes, children[1:-1], strict=True)
        }
        self._fluct = {
            nid: Fluctuation(self.crowd.n_points, ch.fluctuation_time, self._rng[nid])
            for nid in self._nodes
        }
        self._load_kernel()
        # Static nodes: coupling + walls never change, so their spectrum is computed once.
        if ch.model == "hybrid":
            channel = hybrid_channel(scenario, np.random.default_rng(children[-1]))
            self._static = {
                nid: self._hybrid_spectrum(channel, node) for nid, node in self._nodes.items()
            }
        else:
            self._static = {
                nid: self.radar.path_spectrum(
                    *image_paths(node.tx, node.rx, self.walls, ch.reflection_order)
                )
                for nid, node in self._nodes.items()
            }
        self.window = None if window is None else int(window)
        self._static_h: dict[str, npt.NDArray[np.float32]] = {}
        if self.window is not None:
            self.radar.window_grid(self.window)  # validates the window
            self._static_h = {
                nid: self.radar.echo_responses(spec)[:, : self.window].copy()
                for nid, spec in self._static.items()
            }

    def _load_kernel(self) -> None:
        """Call the compiled people-echo kernel once, on the first node, and drop the result:
        numba loads it from its cache (0.5 s) or compiles it (3 s) now, while the network is
        built, not in a node's first TDMA slots. No random draw: the outputs are unchanged."""
        nid = next(iter(self._nodes))
        local = self._local[nid]
        if local is not None:
            self._people_paths_fast(self._nodes[nid], local, np.ones(self.crowd.n_points), 0.0)

    def _local_view(self, node: _Node) -> _LocalView:
        """What of the building can matter to ``node``'s people echoes, found once.

        With a finite ``people_range`` R only bodies whose centre is within R of the
        transmitter contribute points; their points lie within ``R + BODY_REACH`` of it, and
        so does every leg from an antenna to them (the antennas are within ``BODY_REACH``
        of the transmitter). A body blocks a leg only if its centre is within its radius
        of the leg, and a wall changes a leg only if the leg crosses it. People whose whole
        path stays farther than ``R + 2 BODY_REACH + radius`` and walls farther than
        ``R + BODY_REACH`` from the transmitter can therefore never change this node's
        impulse response: leaving them out gives the same result as the full synthesis.
        """
        tx = node.tx.position[0]
        walls = self.walls
        if not np.isfinite(self.people_range):
            near_walls = np.arange(walls.count)
            walkers = np.arange(len(self.crowd.walkers))
        else:
            reach = self.people_range + BODY_REACH
            if walls.count:
                dist, _ = segment_point_distance(walls.start, walls.end, tx[None, :2])
                near_walls = np.flatnonzero(dist[:, 0] <= reach)
            else:
                near_walls = np.arange(0)
            walkers = np.array(
                [
                    i
                    for i, w in enumerate(self.crowd.walkers)
                    if w.min_distance(tx) <= reach + BODY_REACH + w.radius
                ],
                dtype=np.int64,
            )
        near = walls.take(near_walls)
        ant = np.concatenate([node.tx.position, node.rx.position])
        owner_of = np.full(len(self.crowd.walkers), -1, np.int64)
        owner_of[walkers] = np.arange(walkers.size)
        points = np.flatnonzero(owner_of[self.crowd.point_person] >= 0)
        return _LocalView(
            walkers=walkers,
            walls=near,
            antenna_side=wall_side(ant, near) if near.count else np.zeros((ant.shape[0], 0)),
            points=points,
            point_owner=owner_of[self.crowd.point_person[points]],
            antenna_pos=ant,
            antenna_boresight=np.concatenate([node.tx.boresight, node.rx.boresight]),
            antenna_beamwidth=np.concatenate([node.tx.beamwidth, node.rx.beamwidth]),
            wall_excess=np.zeros(near.count) if near.excess is None else near.excess,
            radius=self.crowd.radius[walkers],
        )

    def _hybrid_spectrum(self, channel: HybridChannel, node: _Node) -> np.ndarray:
        """Static spectrum of a node in the hybrid channel on the radar's DFT grid."""
        cfg = self.radar.config
        rows = []
        model = next(m for m in self.scenario.nodes if m.id == node.id)

        def antenna(arr: Antennas, j: int, name: str) -> AntennaArray:
            # A measured table if the node description gives one, else the horn (or omni)
            # of its beam width, as in the image2d model.
            ov = model.antennas.get(name)
            bw = float(arr.beamwidth[j])
            if ov is not None and ov.pattern_table:
                pattern: AntennaPattern = table_pattern(ov.pattern_table)
            elif bw >= 2 * np.pi:
                pattern = OmniPattern()
            else:
                pattern = HornPattern(beamwidth=bw, f0=0.0)
            return AntennaArray(
                position=arr.position[j : j + 1], yaw=arr.boresight[j : j + 1], pattern=pattern
            )

        for i, name in enumerate(node.rx_names):
            # Each receiver separately: the antennas of a node may have different patterns.
            paths = channel.paths(antenna(node.tx, 0, "tx"), antenna(node.rx, i, name))
            rows.append(
                frequency_response(
                    paths, 1, 0.0, cfg.fs / cfg.n, self.radar.n_bins, delay_offset=cfg.t0
                )[0]
            )
        return np.stack(rows)

    @property
    def node_ids(self) -> list[str]:
        """Node ids in scenario order."""
        return list(self._nodes)

    def node_infos(self) -> dict[str, dict]:
        """PROTOCOL.md ``node_info`` fields (without the header) per node id."""
        cfg = self.radar.config
        radar = {
            "fs": float(cfg.fs),
            "n": int(cfg.n if self.window is None else self.window),
            "t0": float(cfg.t0),
            "f_low": float(cfg.f_low),
            "f_high": float(cfg.f_high),
            "rate": float(cfg.rate),
        }
        return {
            nid: {
                "role": "bat",
                "pose": list(node.pose),
                "mobile": False,
                "antennas": {k: dict(v, pos=list(v["pos"])) for k, v in node.antennas.items()},
                "radar": dict(radar),
            }
            for nid, node in self._nodes.items()
        }

    def schedule(self) -> list[dict]:
        """TDMA slots: one per node (its ``tx``), equal shares of the frame, scenario order."""
        period = self.scenario.frame_period
        dur = period / len(self._nodes)
        return [
            {"slot": i, "tx": f"{nid}/tx", "start": i * dur, "duration": dur}
            for i, nid in enumerate(self._nodes)
        ]

    def truth(self, t: float) -> list[dict]:
        """Ground truth ``{id, x, y, vx, vy}`` of the people present at time t, s."""
        return self.crowd.truth(t)

    def people_spectrum(self, node: str, t: float) -> np.ndarray:
        """Channel spectrum of the people's echoes at ``node`` (advances its fluctuation).

        The static channel (coupling, walls, static scatterers) is computed once per node in
        ``__init__``; per call only the people's single-bounce paths are synthesised, and
        (unless ``reference``) only with the people and walls that can reach the node
        (:meth:`_local_view`) and the antennas' wall sides computed once, by the compiled
        kernel :func:`sim_nodes.channel.kernels.body_echo_paths` (the same arithmetic as the
        reference's :meth:`Crowd.scatterers` and :func:`scatter_paths`, in one loop).

        Returns
        -------
        ndarray, complex128, shape (n_rx, n_bins)
        """
        paths = self._people_paths(node, t)
        if isinstance(paths, tuple):
            return self.radar.path_spectrum(*paths)
        if paths is None:
            return np.zeros((self._nodes[node].rx.position.shape[0], self.radar.n_bins), complex)
        return paths

    def _people_paths(
        self, node: str, t: float
    ) -> tuple[np.ndarray, np.ndarray] | np.ndarray | None:
        """What :meth:`people_spectrum` synthesises (advancing the fluctuation): the people's
        paths ``(delays, amplitudes)``, shape (n_rx, P), for :meth:`MSequenceRadar.path_spectrum`
        where the compiled kernel gives them, else the spectrum itself; None when no body
        point can ever reach the node (:meth:`_local_view`: no echo at all)."""
        nd = self._nodes[node]
        local = self._local[node]
        if local is not None and local.points.size == 0:
            # most nodes of a large building (people_range): only the fluctuation's draws,
            # to keep the node's stream; no kinematics, no kernel call, no zero spectrum
            self._fluct[node].advance(t)
            return None
        amp_fluct = self._fluct[node].step(t)
        if local is not None:
            return self._people_paths_fast(nd, local, amp_fluct, t)
        if local is None:
            body = self.crowd.scatterers(t)
            walls, antenna_side = self.walls, None
        else:
            body = self.crowd.scatterers(t, local.walkers)
            walls, antenna_side = local.walls, local.antenna_side
        n_rx = nd.rx.position.shape[0]
        if np.isfinite(self.people_range) and body.points.shape[0]:
            far = np.hypot(*(body.centres - nd.tx.position[0, :2]).T) > self.people_range
            if far.any():
                keep = ~far[body.owner]
                # Owners index the blockers, which stay complete (a far body cannot lie on
                # a leg shorter than the range anyway).
                body = dataclasses.replace(
                    body,
                    points=body.points[keep],
                    normals=body.normals[keep],
                    rcs=body.rcs[keep],
                    owner=body.owner[keep],
                    index=body.index[keep],
                )
        if body.points.shape[0] == 0:
            return np.zeros((n_rx, self.radar.n_bins), complex)
        delays, amps = scatter_paths(
            nd.tx,
            nd.rx,
            body.points,
            body.rcs,
            walls,
            normals=body.normals,
            owner=body.owner,
            blockers=body.centres,
            blocker_radius=body.radius,
            shadow_db=self.scenario.channel.shadow_db,
            antenna_side=antenna_side,
        )
        amps = amps * (BODY_REFLECTION_SIGN * amp_fluct[body.index])[None, :]
        return self.radar.path_spectrum(delays, amps)

    def _people_paths_fast(
        self, nd: _Node, local: _LocalView, amp_fluct: np.ndarray, t: float
    ) -> tuple[np.ndarray, np.ndarray] | None:
        crowd, walls = self.crowd, local.walls
        n_rx = nd.rx.position.shape[0]
        delays = np.empty((n_rx, local.points.size))
        amps = np.empty((n_rx, local.points.size))
        count = body_echo_paths(
            t,
            crowd.state(t, local.walkers.tolist()),
            local.points,
            local.point_owner,
            crowd.body_point,
            crowd.body_normal,
            crowd.gait_phase,
            crowd.point_height,
            crowd.point_rcs,
            BODY_REFLECTION_SIGN * amp_fluct,
            crowd.gait_amplitude,
            crowd.breathing_amplitude,
            local.radius,
            self.people_range,
            local.antenna_pos,
            local.antenna_boresight,
            local.antenna_beamwidth,
            local.antenna_side,
            walls.start,
            walls.end,
            walls.height,
            walls.transmission,
            local.wall_excess,
            float(self.scenario.channel.shadow_db),
            delays,
            amps,
        )
        if count == 0:
            return None  # no echo now: the static spectrum alone, the same bits as adding 0
        return delays[:, :count], amps[:, :count]

    def acquire(self, node: str, t: float) -> tuple[str, tuple[str, ...], npt.NDArray[np.float32]]:
        """One acquisition of ``node``'s own transmitter at its receivers.

        Parameters
        ----------
        node : str
            Node id.
        t : float
            Network time of the acquisition, s.

        Returns
        -------
        tx : str
            ``"{node}/tx"``.
        rx : tuple of str
            Receiver names, one per row of ``h`` (``("rx1", "rx2")``).
        h : ndarray, float32, shape (n_rx, n)
            Impulse responses, sample k at ``t0 + k / fs`` after emission.
        """
        if node not in self._nodes:
            raise KeyError(f"unknown node {node!r}")
        if self.window is not None:
            return self._acquire_windowed([(node, t)])[0]
        spec = self._static[node] + self.people_spectrum(node, t)
        h = self.radar.impulse_response(spec, self._rng[node])
        return f"{node}/tx", self._nodes[node].rx_names, h

    def _acquire_windowed(
        self, requests: Sequence[tuple[str, float]]
    ) -> list[tuple[str, tuple[str, ...], npt.NDArray[np.float32]]]:
        """:meth:`acquire_many` with a ``window``: static response + the people's echoes
        (inverse FFT of their spectra, for the acquisitions that have any) + the window's
        noise, in the time domain. Row by row the same arithmetic whatever the batch, and
        each node's generator draws its fluctuation, then its noise: bit for bit the same
        in a batch and one by one."""
        assert self.window is not None
        nodes = [node for node, _ in requests]
        n_rx = self._nodes[nodes[0]].rx.position.shape[0]
        people = [self._people_paths(node, t) for node, t in requests]
        h = np.stack([self._static_h[node] for node in nodes])
        echo = [i for i, p in enumerate(people) if p is not None]
        if echo:
            spectra = iter(self.radar.path_spectra([p for p in people if isinstance(p, tuple)]))
            spec = np.empty((len(echo), n_rx, self.radar.n_bins), np.complex64)
            for j, i in enumerate(echo):
                p = people[i]
                spec[j] = next(spectra) if isinstance(p, tuple) else p
            h[echo] += self.radar.echo_responses(spec)[..., : self.window]
        if self.radar.config.noise:
            h += self.radar.window_noise([self._rng[node] for node in nodes], n_rx, self.window)
        return [(f"{node}/tx", self._nodes[node].rx_names, h[i]) for i, node in enumerate(nodes)]

    def acquire_many(
        self, requests: Sequence[tuple[str, float]]
    ) -> list[tuple[str, tuple[str, ...], npt.NDArray[np.float32]]]:
        """:meth:`acquire` of several ``(node, t)`` at once, in the order given.

        The people's echoes are synthesised per acquisition as in :meth:`acquire`; the
        static channel, the system response, the noise transform and the inverse FFT run
        once over the batch (:meth:`MSequenceRadar.impulse_responses`). Each node's
        generator draws what it would in :meth:`acquire` (the amplitude fluctuation, then the
        noise), and the people echoes use no random numbers, so every impulse response is
        bit for bit what the same calls of :meth:`acquire` in this order give. A node that
        appears twice (two of its acquisitions in one batch) would draw its second
        fluctuation before its first noise: then the requests are served one by one.

        Returns
        -------
        list of ``(tx, rx, h)`` as :meth:`acquire` returns them; the ``h`` are rows of one
        array.
        """
        nodes = [node for node, _ in requests]
        for node in nodes:
            if node not in self._nodes:
                raise KeyError(f"unknown node {node!r}")
        n_rx = {self._nodes[node].rx.position.shape[0] for node in nodes}
        if len(set(nodes)) < len(nodes) or len(n_rx) > 1:
            return [self.acquire(node, t) for node, t in requests]
        if not requests:
            return []
        if self.window is not None:
            return self._acquire_windowed(requests)
        spec = np.empty((len(requests), n_rx.pop(), self.radar.n_bins), np.complex64)
        people = [self._people_paths(node, t) for node, t in requests]
        # the people's path spectra of the batch together (bit for bit one by one)
        spectra = iter(self.radar.path_spectra([p for p in people if isinstance(p, tuple)]))
        for i, node in enumerate(nodes):
            p = people[i]
            # the same complex64 rounding as acquire's asarray (adding no echo: the static
            # spectrum itself, the same bits)
            if p is None:
                spec[i] = self._static[node]
            else:
                spec[i] = self._static[node] + (next(spectra) if isinstance(p, tuple) else p)
        h = self.radar.impulse_responses(spec, [self._rng[node] for node in nodes])
        return [(f"{node}/tx", self._nodes[node].rx_names, h[i]) for i, node in enumerate(nodes)]

    def static_response(self, node: str) -> npt.NDArray[np.float32]:
        """Noise-free background (coupling + walls) of ``node``, float32 (n_rx, n), n the
        ``window`` if one is set."""
        if self.window is not None:
            return self._static_h[node].copy()
        return self.radar.impulse_response(self._static[node])
