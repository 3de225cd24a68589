"""An outside recording generator, independent of uwbnet, written from PROTOCOL.md alone.

It plays the role of a third-party tool (or a hidden acceptance test): it imports nothing
from ``protocol``, ``sim_nodes``, ``node_agent`` or ``fusion_center``, builds every msgpack map
by hand and writes MCAP with the ``mcap`` package's ``Writer`` and its default (ZSTD) chunk
compression. Its physics is deliberately simpler than, and different from, ``sim_nodes``:

- a rectangular hall, ``n_sensors`` bat-type nodes on its walls at heights 1.0-1.5 m with
  headings into the hall +-40 deg; a bat node has ``tx`` at (0, 0, 0) and two receivers at
  (0, +b, 0), (0, -b, 0) in its frame, b in 0.3-0.6 m, Gaussian beams of 3 dB width 1.5-2.1 rad;
- one impulse response per receiver and TDMA slot (monostatic: each node hears its own tx),
  the sum of band-limited pulses at exact (sub-sample) bistatic delays of: the direct path
  (when inside the window), the specular reflections of the four walls (image method),
  2-4 static furniture scatterers and every person as 3-6 scattering points on a 0.4 m body
  (one of them a swinging limb), with AR(1)-fluctuating amplitudes, 1/(d1 d2) spreading,
  antenna gains, and white Gaussian noise;
- three radar families: a real band-pass radar (Gaussian-modulated cosine whose -10 dB band is
  ``[f_low, f_high]``), a real baseband radar (Gaussian monocycle, band up to ``f_high``) and a
  complex-baseband radar (``<c8``, carrier ``fc``, analytic form of the modulated pulse);
- a cropped window: sample k is at ``t0 + k / fs`` with ``t0`` 5-20 ns (1.5-6 m of bistatic
  range cut away, so the direct path is outside the window);
- people walking random waypoints at 0.5-1.5 m/s with a simple mutual repulsion, entering at
  a door and leaving through one at random times so that their count stays in
  ``[n_min, n_max]``.

Every message has ``v``, ``kind``, ``src``, ``seq`` (per publisher) and ``t``; ``log_time`` and
``publish_time`` are ``t`` in nanoseconds; ``node_info`` of every node comes first, then per
TDMA frame ``truth`` and the nodes' ``ir`` in slot order.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
from mcap.writer import Writer

C = 299792458.0
RX_NAMES = ("rx_l", "rx_r")  # not the names our own simulator uses


@dataclass(frozen=True, slots=True, kw_only=True)
class OutsideConfig:
    """What an outside test may vary; ``None`` means drawn from the seeded generator."""

    seed: int
    hall: tuple[float, float] = (14.0, 10.0)
    n_sensors: int = 4
    n_initial: int = 3
    n_min: int = 2
    n_max: int = 5
    duration: float = 30.0
    radar: str = "band"  # "band" | "baseband" | "complex"
    fs: float | None = None
    n: int | None = None
    t0: float | None = None
    rate: float | None = None
    snr_db: float = 28.0  # peak SNR of a 1 m^2 person at 5 m + 5 m on both boresights
    t_start: float = 0.0  # network time of frame 0
    net: str = "hallx"
    event_interval: tuple[float, float] = (4.0, 9.0)  # s between enter/leave decisions


@dataclass(slots=True, kw_only=True)
class _Radar:
    kind: str
    fs: float
    n: int
    t0: float
    f_low: float
    f_high: float
    rate: float
    fc: float
    sigma: float  # Gaussian envelope width, s

    def wire(self) -> dict[str, Any]:
        out: dict[str, Any] = {
            "fs": self.fs,
            "n": self.n,
            "t0": self.t0,
            "f_low": self.f_low,
            "f_high": self.f_high,
            "rate": self.rate,
        }
        if self.kind == "complex":
            out["fc"] = self.fc
        return out


@dataclass(slots=True, kw_only=True)
class Scene:
    """Everything drawn for one recording (also returned to the caller for reporting)."""

    config: OutsideConfig
    radar: _Radar
    node_ids: list[str]
    poses: np.ndarray  # (S, 4) x, y, z, yaw
    baselines: np.ndarray  # (S,) b, m
    beamwidths: np.ndarray  # (S,)
    doors: np.ndarray  # (D, 2)
    furniture: np.ndarray  # (F, 3) x, y, z
    furniture_rcs: np.ndarray  # (F,)
    noise_std: float
    summary: dict[str, Any] = field(default_factory=dict)


def _array(a: np.ndarray) -> dict[str, Any]:
    dtype = "<c8" if np.iscomplexobj(a) else "<f4"
    a = np.ascontiguousarray(a, dtype=np.dtype(dtype))
    return {"dtype": dtype, "shape": list(a.shape), "data": a.tobytes()}


def _wall_point(s: float, w: float, h: float, inset: float) -> tuple[float, float, float]:
    """Point at perimeter abscissa ``s`` (counter-clockwise from (0, 0)) and inward normal yaw."""
    s = s % (2 * (w + h))
    if s < w:
        return s, inset, math.pi / 2
    if s < w + h:
        return w - inset, s - w, math.pi
    if s < 2 * w + h:
        return w - (s - w - h), h - inset, -math.pi / 2
    return inset, h - (s - 2 * w - h), 0.0


def _draw_radar(cfg: OutsideConfig, rng: np.random.Generator, max_range: float) -> _Radar:
    if cfg.radar == "complex":
        fs = cfg.fs if cfg.fs is not None else float(rng.uniform(2.5e9, 4.0e9))
        fc = float(rng.choice([3.9936e9, 4.4928e9, 6.4896e9]))
        bw = float(min(rng.uniform(1.0e9, 1.6e9), 0.6 * fs))
        f_low, f_high = fc - bw / 2, fc + bw / 2
        sigma = 0.483 / bw  # the complex envelope's spectrum is 10 dB down at the band edges
    elif cfg.radar == "band":
        fs = cfg.fs if cfg.fs is not None else float(rng.uniform(8e9, 12e9))
        fc = 0.0
        f_low, f_high = float(rng.uniform(0.4e9, 0.8e9)), float(rng.uniform(4.0e9, 4.6e9))
        sigma = 0.483 / (f_high - f_low)
    elif cfg.radar == "baseband":
        fs = cfg.fs if cfg.fs is not None else float(rng.uniform(8e9, 12e9))
        fc = 0.0
        f_low, f_high = 0.0, fs / 2
        sigma = 3.0 / (2 * math.pi * 0.6 * f_high)  # monocycle spectrum peaks at 0.2 fs
    else:
        raise ValueError(f"unknown radar kind {cfg.radar!r}")
    t0 = cfg.t0 if cfg.t0 is not None else float(rng.uniform(5e-9, 20e-9))
    need = math.ceil((max_range / C - t0) * fs) + 64
    n = cfg.n if cfg.n is not None else max(int(rng.integers(1000, 2501)), need)
    rate = cfg.rate if cfg.rate is not None else float(rng.choice([20.0, 25.0, 30.0, 40.0, 50.0]))
    return _Radar(
        kind=cfg.radar, fs=fs, n=n, t0=t0, f_low=f_low, f_high=f_high, rate=rate, fc=fc, sigma=sigma
    )


def build_scene(
    cfg: OutsideConfig, rng: np.random.Generator, rng_radar: np.random.Generator
) -> Scene:
    w, h = cfg.hall
    perim = 2 * (w + h)
    # Sensors spread along the perimeter, not within 1 m of a corner.
    corners = np.array([0.0, w, w + h, 2 * w + h])
    abscissae: list[float] = []
    base = rng.uniform(0, perim)
    for i in range(cfg.n_sensors):
        for _ in range(100):
            s = (base + (i + rng.uniform(-0.25, 0.25)) * perim / cfg.n_sensors) % perim
            dc = np.abs((s - corners + perim / 2) % perim - perim / 2).min()
            if dc > 1.0:
                break
        abscissae.append(float(s))
    poses = []
    for s in abscissae:
        x, y, normal = _wall_point(s, w, h, 0.15)
        yaw = normal + rng.uniform(-math.radians(40), math.radians(40))
        yaw = (yaw + math.pi) % (2 * math.pi) - math.pi
        poses.append([x, y, float(rng.uniform(1.0, 1.5)), yaw])
    # Doors: one or two, away from sensors and corners.
    doors = []
    for _ in range(int(rng.integers(1, 3))):
        for _ in range(200):
            s = float(rng.uniform(0, perim))
            d_sensor = np.abs((s - np.array(abscissae) + perim / 2) % perim - perim / 2).min()
            d_corner = np.abs((s - corners + perim / 2) % perim - perim / 2).min()
            if d_sensor > 1.5 and d_corner > 1.2:
                break
        x, y, _ = _wall_point(s, w, h, 0.35)
        doors.append([x, y])
    n_furn = int(rng.integers(2, 5))
    furniture = np.column_stack(
        [
            rng.uniform(0.5, w - 0.5, n_furn),
            rng.uniform(0.5, h - 0.5, n_furn),
            rng.uniform(0.4, 1.2, n_furn),
        ]
    )
    radar = _draw_radar(cfg, rng_radar, max_range=2.0 * math.hypot(w, h) + 2.0)
    a_ref = math.sqrt(1.0 / (4 * math.pi)) / 25.0
    return Scene(
        config=cfg,
        radar=radar,
        node_ids=[f"radar-{i + 1:02d}" for i in range(cfg.n_sensors)],
        poses=np.array(poses),
        baselines=rng.uniform(0.3, 0.6, cfg.n_sensors),
        beamwidths=rng.uniform(1.5, 2.1, cfg.n_sensors),
        doors=np.array(doors),
        furniture=furniture,
        furniture_rcs=rng.uniform(0.3, 3.0, n_furn),
        noise_std=a_ref / 10 ** (cfg.snr_db / 20),
    )


def simulate_people(
    cfg: OutsideConfig, scene: Scene, rng: np.random.Generator, times: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Walk people with a waypoint model plus repulsion on the frame grid ``times``.

    Returns positions (T, P, 2), velocities (T, P, 2) and presence (T, P) bool, P the number of
    people who ever appear.
    """
    w, h = cfg.hall
    margin = 0.6
    n_cap = cfg.n_max + int(cfg.duration / cfg.event_interval[0]) + 2
    pos = np.zeros((n_cap, 2))
    vel = np.zeros((n_cap, 2))
    wp = np.zeros((n_cap, 2))
    speed = np.zeros(n_cap)
    active = np.zeros(n_cap, bool)
    leaving = np.zeros(n_cap, bool)
    n_used = 0

    def new_waypoint(p: np.ndarray) -> np.ndarray:
        for _ in range(50):
            q = rng.uniform([margin, margin], [w - margin, h - margin])
            if np.hypot(*(q - p)) > 2.0:
                return q
        return q

    for _ in range(cfg.n_initial):  # people already inside at the start, 1.5 m apart
        for _ in range(200):
            p = rng.uniform([1.0, 1.0], [w - 1.0, h - 1.0])
            if n_used == 0 or np.hypot(*(pos[:n_used] - p).T).min() > 1.5:
                break
        pos[n_used], wp[n_used] = p, new_waypoint(p)
        speed[n_used], active[n_used] = rng.uniform(0.5, 1.5), True
        n_used += 1

    dt = float(times[1] - times[0])
    next_event = float(rng.uniform(*cfg.event_interval))
    out_pos = np.zeros((len(times), n_cap, 2))
    out_vel = np.zeros((len(times), n_cap, 2))
    out_act = np.zeros((len(times), n_cap), bool)
    for k, t in enumerate(times - times[0]):
        if t >= next_event:
            next_event = t + float(rng.uniform(*cfg.event_interval))
            n_now = int(active.sum())
            n_staying = int((active & ~leaving).sum())
            enter = n_now < cfg.n_max and (n_staying <= cfg.n_min or rng.uniform() < 0.5)
            if enter and n_used < n_cap:
                door = scene.doors[int(rng.integers(len(scene.doors)))]
                pos[n_used], vel[n_used] = door, 0.0
                wp[n_used] = new_waypoint(door)
                speed[n_used], active[n_used] = rng.uniform(0.5, 1.5), True
                n_used += 1
            elif n_staying > cfg.n_min:
                who = rng.choice(np.flatnonzero(active & ~leaving))
                door_d = np.hypot(*(scene.doors - pos[who]).T)
                leaving[who] = True
                wp[who] = scene.doors[int(np.argmin(door_d))]
        idx = np.flatnonzero(active)
        d = wp[idx] - pos[idx]
        dist = np.hypot(d[:, 0], d[:, 1])
        desired = speed[idx, None] * d / np.maximum(dist, 1e-9)[:, None]
        # Pairwise repulsion within 1.2 m so that people pass rather than overlap.
        diff = pos[idx, None, :] - pos[None, idx, :]
        pd = np.hypot(diff[..., 0], diff[..., 1]) + np.eye(len(idx)) * 1e9
        push = np.clip(1.2 - pd, 0, None) / np.maximum(pd, 1e-3) * 1.5
        desired = desired + (push[..., None] * diff).sum(axis=1)
        v_new = 0.7 * vel[idx] + 0.3 * desired  # smooth: people do not turn instantly
        vn = np.hypot(v_new[:, 0], v_new[:, 1])
        v_new *= (np.minimum(vn, 1.6) / np.maximum(vn, 1e-9))[:, None]
        vel[idx] = v_new
        pos[idx] += v_new * dt
        lo = np.where(leaving[idx], 0.3, margin)[:, None]
        pos[idx] = np.clip(pos[idx], lo, np.array([w, h]) - lo)
        out_pos[k], out_vel[k], out_act[k] = pos, vel, active
        # Arrivals: a new waypoint, or leaving through the door.
        arrived = idx[dist < 0.35]
        for p in arrived:
            if leaving[p]:
                active[p] = False
            else:
                wp[p], speed[p] = new_waypoint(pos[p]), rng.uniform(0.5, 1.5)
    return out_pos[:, :n_used], out_vel[:, :n_used], out_act[:, :n_used]


def _gain(angle: np.ndarray, beamwidth: np.ndarray) -> np.ndarray:
    """Amplitude gain of a Gaussian beam, -3 dB in power at +-beamwidth/2, -25 dB floor."""
    a = (angle + np.pi) % (2 * np.pi) - np.pi
    return np.maximum(np.exp(-2 * math.log(2) * (a / beamwidth) ** 2), 10 ** (-25 / 20))


def _synthesize(
    radar: _Radar, delays: np.ndarray, amps: np.ndarray, n_rows: int, row: np.ndarray
) -> np.ndarray:
    """Sum of pulses at exact delays, evaluated only within +-6 sigma of each (scatter-add)."""
    half = math.ceil(6 * radar.sigma * radar.fs) + 1
    k = np.round((delays - radar.t0) * radar.fs).astype(np.int64)
    keep = (k > -half) & (k < radar.n + half)
    k, delays, amps, row = k[keep], delays[keep], amps[keep], row[keep]
    idx = k[:, None] + np.arange(-half, half + 1)[None, :]
    tau = radar.t0 + idx / radar.fs - delays[:, None]
    env = np.exp(-0.5 * (tau / radar.sigma) ** 2)
    if radar.kind == "complex":
        # Baseband equivalent of a delayed carrier pulse: e^{-j 2 pi fc delay} env(t - delay).
        vals = env * np.exp(-2j * np.pi * radar.fc * delays)[:, None] * amps[:, None]
        out = np.zeros((n_rows, radar.n), np.complex128)
    elif radar.kind == "band":
        fm = 0.5 * (radar.f_low + radar.f_high)
        vals = env * np.cos(2 * np.pi * fm * tau) * amps[:, None]
        out = np.zeros((n_rows, radar.n))
    else:
        vals = -tau / radar.sigma * np.exp(0.5) * env * amps[:, None]  # monocycle, peak 1
        out = np.zeros((n_rows, radar.n))
    ok = (idx >= 0) & (idx < radar.n)
    rows = np.broadcast_to(row[:, None], idx.shape)
    np.add.at(out, (rows[ok], idx[ok]), vals[ok])
    return out


def generate(cfg: OutsideConfig, path: str | Path) -> Scene:
    """Write a recording of ``cfg`` to ``path``; return the drawn scene (for reports)."""
    # Independent streams, so that changing the radar keeps the hall and the people.
    rng, rng_radar, rng_people, rng_noise = (
        np.random.default_rng(s) for s in np.random.SeedSequence(cfg.seed).spawn(4)
    )
    scene = build_scene(cfg, rng, rng_radar)
    radar, w, h = scene.radar, *cfg.hall
    period = 1.0 / radar.rate
    n_frames = round(cfg.duration * radar.rate)
    frame_t = cfg.t_start + np.arange(n_frames) * period
    ppos, pvel, pact = simulate_people(cfg, scene, rng_people, frame_t)
    n_people = ppos.shape[1]
    S = cfg.n_sensors
    slot_dur = period / S

    # Antenna positions in the world, (S, 3, 3): tx, rx_l, rx_r.
    yaw = scene.poses[:, 3]
    cy, sy = np.cos(yaw), np.sin(yaw)
    local_y = np.stack([np.zeros(S), scene.baselines, -scene.baselines], axis=1)  # (S, 3)
    ant = np.zeros((S, 3, 3))
    ant[..., 0] = scene.poses[:, None, 0] - sy[:, None] * local_y
    ant[..., 1] = scene.poses[:, None, 1] + cy[:, None] * local_y
    ant[..., 2] = scene.poses[:, None, 2]

    # Body model: 3-6 points per person within 0.2 m of the centre, one a swinging limb.
    n_pts = rng.integers(3, 7, n_people)
    P = int(n_pts.max())
    body_off = rng.normal(0, 0.1, (n_people, P, 2))
    body_off *= np.minimum(1.0, 0.2 / np.maximum(np.hypot(*body_off.T).T, 1e-9))[..., None]
    body_z = rng.uniform(0.9, 1.5, (n_people, P))
    body_on = np.arange(P)[None, :] < n_pts[:, None]
    body_rms = 1.0 / np.sqrt(n_pts)[:, None]  # total RCS about 1 m^2 per person
    rho = np.sqrt(1 / (4 * math.pi))
    fluct = rng.normal(size=(n_people, P, 2))
    alpha = math.exp(-period / 0.1)  # AR(1), 0.1 s correlation time

    # Static paths per (node, receiver): walls by the image method, furniture, direct path.
    walls = [(0, 0.0), (0, w), (1, 0.0), (1, h)]  # (axis, coordinate)
    st_delay, st_amp = [], []
    for s in range(S):
        tx = ant[s, 0]
        for r in (1, 2):
            rx = ant[s, r]
            dl, am = [], []
            d_direct = float(np.linalg.norm(rx[:2] - tx[:2]))
            dl.append(d_direct / C)
            am.append(float(_gain(np.array(np.pi / 2), scene.beamwidths[s]) ** 2) / d_direct)
            for axis, coord in walls:
                img = tx.copy()
                img[axis] = 2 * coord - img[axis]
                L = float(np.linalg.norm(rx - img))
                # Specular point: where the image ray crosses the wall.
                u = (coord - rx[axis]) / (img[axis] - rx[axis])
                sp = rx + u * (img - rx)
                g = (
                    _gain(
                        np.array([math.atan2(sp[1] - tx[1], sp[0] - tx[0]) - yaw[s]]),
                        scene.beamwidths[s],
                    )[0]
                    * _gain(
                        np.array([math.atan2(sp[1] - rx[1], sp[0] - rx[0]) - yaw[s]]),
                        scene.beamwidths[s],
                    )[0]
                )
                dl.append(L / C)
                am.append(-0.5 * g / L)
            for f, rcs in zip(scene.furniture, scene.furniture_rcs, strict=True):
                d1, d2 = np.linalg.norm(f - tx), np.linalg.norm(f - rx)
                g = (
                    _gain(
                        np.array([math.atan2(f[1] - tx[1], f[0] - tx[0]) - yaw[s]]),
                        scene.beamwidths[s],
                    )[0]
                    * _gain(
                        np.array([math.atan2(f[1] - rx[1], f[0] - rx[0]) - yaw[s]]),
                        scene.beamwidths[s],
                    )[0]
                )
                dl.append((d1 + d2) / C)
                am.append(rho * math.sqrt(rcs) * g / (d1 * d2))
            st_delay.append(dl)
            st_amp.append(am)
    st_delay_a = np.array(st_delay)  # (S*2, Q)
    st_amp_a = np.array(st_amp)
    st_row = np.broadcast_to(np.arange(2)[:, None], (2, st_delay_a.shape[1]))

    is_complex = radar.kind == "complex"
    packer = msgpack.Packer(use_bin_type=True)
    seq = dict.fromkeys([*scene.node_ids, "outside-sim"], 0)
    schema = json.dumps({"type": "object"}).encode()
    path = Path(path)
    n_messages = 0
    with path.open("wb") as stream:
        writer = Writer(stream)
        writer.start(profile="", library="outside-generator")
        schemas = {
            k: writer.register_schema(name=f"uwbnet.{k}", encoding="jsonschema", data=schema)
            for k in ("node_info", "ir", "truth")
        }
        channels: dict[str, int] = {}

        def emit(topic: str, kind: str, src: str, t: float, body: dict[str, Any]) -> None:
            nonlocal n_messages
            if topic not in channels:
                channels[topic] = writer.register_channel(
                    topic=topic, message_encoding="msgpack", schema_id=schemas[kind]
                )
            msg = {"v": 1, "kind": kind, "src": src, "seq": seq[src], "t": float(t), **body}
            seq[src] += 1
            ns = round(t * 1e9)
            writer.add_message(
                channel_id=channels[topic],
                log_time=ns,
                publish_time=ns,
                data=packer.pack(msg),
                sequence=seq[src] - 1,
            )
            n_messages += 1

        for s, nid in enumerate(scene.node_ids):
            b, bw = float(scene.baselines[s]), float(scene.beamwidths[s])
            antennas = {
                "tx": {"pos": [0.0, 0.0, 0.0], "tx": True, "rx": False},
                RX_NAMES[0]: {"pos": [0.0, b, 0.0], "tx": False, "rx": True},
                RX_NAMES[1]: {"pos": [0.0, -b, 0.0], "tx": False, "rx": True},
            }
            for a in antennas.values():
                a.update(boresight=0.0, beamwidth=bw)
            emit(
                f"uwbnet/{cfg.net}/node/{nid}/info",
                "node_info",
                nid,
                cfg.t_start,
                {
                    "role": "bat",
                    "pose": [float(v) for v in scene.poses[s]],
                    "mobile": False,
                    "antennas": antennas,
                    "radar": radar.wire(),
                },
            )

        for k in range(n_frames):
            tf = float(frame_t[k])
            on = np.flatnonzero(pact[k])
            emit(
                f"uwbnet/{cfg.net}/sim/truth",
                "truth",
                "outside-sim",
                tf,
                {
                    "targets": [
                        {
                            "id": int(p + 1),
                            "x": float(ppos[k, p, 0]),
                            "y": float(ppos[k, p, 1]),
                            "vx": float(pvel[k, p, 0]),
                            "vy": float(pvel[k, p, 1]),
                        }
                        for p in on
                    ],
                    "nodes": {},
                },
            )
            # Amplitude fluctuation of every body point (AR(1), one step per frame).
            fluct = alpha * fluct + math.sqrt(1 - alpha**2) * rng_noise.normal(size=fluct.shape)
            if is_complex:
                pt_amp = body_rms * (0.7 + 0.5 * (fluct[..., 0] + 1j * fluct[..., 1]) / 1.414)
            else:
                pt_amp = body_rms * np.maximum(0.1, 1.0 + 0.4 * fluct[..., 0])
            for s, nid in enumerate(scene.node_ids):
                t_ir = tf + s * slot_dur
                dt_slot = s * slot_dur
                rows_d = [st_delay_a[2 * s : 2 * s + 2]]
                rows_a = [st_amp_a[2 * s : 2 * s + 2].astype(complex if is_complex else float)]
                rows_r = [st_row]
                if len(on):
                    centre = ppos[k, on] + pvel[k, on] * dt_slot  # (M, 2)
                    vdir = pvel[k, on] / np.maximum(np.hypot(*pvel[k, on].T), 0.2)[:, None]
                    off = body_off[on].copy()
                    off[:, 0] += (
                        0.15 * np.sin(2 * np.pi * 1.8 * (t_ir - cfg.t_start))[None] * vdir
                    )  # limb swing along the walking direction
                    pts = np.concatenate(
                        [centre[:, None, :] + off, body_z[on][..., None]], axis=-1
                    )  # (M, P, 3)
                    tx = ant[s, 0]
                    d1 = np.linalg.norm(pts - tx, axis=-1)
                    g_tx = _gain(
                        np.arctan2(pts[..., 1] - tx[1], pts[..., 0] - tx[0]) - yaw[s],
                        scene.beamwidths[s],
                    )
                    for r in (1, 2):
                        rx = ant[s, r]
                        d2 = np.linalg.norm(pts - rx, axis=-1)
                        g_rx = _gain(
                            np.arctan2(pts[..., 1] - rx[1], pts[..., 0] - rx[0]) - yaw[s],
                            scene.beamwidths[s],
                        )
                        a = rho * pt_amp[on] * g_tx * g_rx / (d1 * d2)
                        m = body_on[on]
                        rows_d.append(((d1 + d2) / C)[m][None])
                        rows_a.append(a[m][None])
                        rows_r.append(np.full((1, int(m.sum())), r - 1))
                delays = np.concatenate([x.ravel() for x in rows_d])
                amps = np.concatenate([x.ravel() for x in rows_a])
                rows = np.concatenate([x.ravel() for x in rows_r])
                hh = _synthesize(radar, delays, amps, 2, rows)
                noise = rng_noise.normal(0, scene.noise_std, (2, radar.n))
                if is_complex:
                    noise = (
                        noise + 1j * rng_noise.normal(0, scene.noise_std, (2, radar.n))
                    ) / 1.414
                hh = (hh + noise).astype(np.complex64 if is_complex else np.float32)
                emit(
                    f"uwbnet/{cfg.net}/node/{nid}/ir",
                    "ir",
                    nid,
                    t_ir,
                    {
                        "tx": f"{nid}/tx",
                        "rx": list(RX_NAMES),
                        "slot": s,
                        "frame": k,
                        "h": _array(hh),
                    },
                )
        writer.finish()

    scene.summary = {
        "hall": list(cfg.hall),
        "sensors": [
            {
                "id": nid,
                "pose": [round(float(v), 3) for v in scene.poses[s]],
                "b": round(float(scene.baselines[s]), 3),
                "beamwidth": round(float(scene.beamwidths[s]), 3),
            }
            for s, nid in enumerate(scene.node_ids)
        ],
        "radar": {**radar.wire(), "kind": radar.kind, "sigma": radar.sigma},
        "snr_db": cfg.snr_db,
        "doors": scene.doors.round(2).tolist(),
        "furniture": scene.furniture.round(2).tolist(),
        "people_total": int(n_people),
        "count_range": [int(pact.sum(1).min()), int(pact.sum(1).max())],
        "messages": n_messages,
    }
    return scene


def read_truth(path: str | Path) -> tuple[np.ndarray, list[dict[int, tuple[float, float]]]]:
    """Truth times and per-time {id: (x, y)} from a recording, with the ``mcap`` reader only."""
    from mcap.reader import make_reader

    times: list[float] = []
    sets: list[dict[int, tuple[float, float]]] = []
    with Path(path).open("rb") as f:
        for _, channel, message in make_reader(f).iter_messages():
            if not channel.topic.endswith("/sim/truth"):
                continue
            m = msgpack.unpackb(message.data, raw=False)
            times.append(float(m["t"]))
            sets.append({int(g["id"]): (float(g["x"]), float(g["y"])) for g in m["targets"]})
    order = np.argsort(times)
    return np.asarray(times)[order], [sets[i] for i in order]
