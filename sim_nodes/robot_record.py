"""Robot recordings: a ``[robot]`` scenario's data set as a PROTOCOL.md recording.

A ``[robot]`` scenario (room_pillar, corridor_L, office) has no static nodes: a bat-type robot
stops at positions and turns on the spot. :func:`write_robot_recording` turns the hybrid
channel's frequency responses of every stop and heading (a
:class:`~sim_nodes.propagation.RobotDataset`, as ``uwbnet channel dataset`` computes it) into
the recording a real robot would leave:

* one ``node_info`` of the robot (role ``robot``, ``mobile`` true, antennas ``tx``, ``rx1``,
  ``rx2`` at the scenario's positions in the node frame, ``radar`` sampling of the band);
* per stop and heading one ``ir`` (``tx`` ``"{robot}/tx"``, ``rx`` ``["rx1", "rx2"]``, ``h``
  ``<f4`` ``[2, n]`` real impulse responses, ``pose`` the true ``[x, y, 0, yaw]``) followed by
  one ``truth`` with ``nodes`` ``{robot: pose}``.

Impulse responses (:func:`frequency_to_ir`): the Friis-scaled transfer function on the
channel band (``c / 4 pi f`` times the data set's ``1/d`` scale) is Hann-windowed, placed on
the positive-frequency bins of an ``N``-point real FFT grid with the data set's frequency step
``df`` and inverted, so the equivalent sample rate is ``fs = N df`` (``N`` chosen so that
``fs >= 2.4 f_high``: the band is resolved without aliasing) and sample ``k`` lies at
``k / fs`` after emission (``t0 = 0``). The recording keeps the first ``n`` samples
(``max_delay``, 100 ns = 30 m of bistatic path by default). Amplitudes are scaled so that a
single path of Friis amplitude ``a`` peaks at about ``a``.

Noise: white complex Gaussian noise is added to every frequency bin before the window with
variance ``mean|H|^2 / 10^(snr_db / 10)``, the mean taken over all bins and acquisitions of
the recording: ``snr_db`` is the in-band signal-to-noise ratio of the average impulse response
(the strong direct Tx-Rx coupling included). Stop ``s`` draws its noise from
``default_rng([seed, s])``, so the output does not depend on how the data set was split over
worker processes.
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from protocol import Ir, NodeInfo, Truth, keys
from protocol.messages import Antenna, RadarInfo
from protocol.recording import RecordingWriter
from sim_nodes.channel.synth import friis_amplitude
from sim_nodes.propagation import RobotDataset
from sim_nodes.scene import Scenario

#: Default in-band SNR of the recorded impulse responses, dB (see the module docstring).
DEFAULT_SNR_DB = 30.0
#: Default length of the recorded impulse responses: 100 ns = 30 m of bistatic path.
DEFAULT_MAX_DELAY = 100e-9
#: Equivalent sample rate over the upper band edge (> 2: the band is resolved).
OVERSAMPLING = 2.4
#: Antenna names of the robot (PROTOCOL.md ``node_info.antennas``).
TX, RX1, RX2 = "tx", "rx1", "rx2"


def _fast_length(n: int) -> int:
    """Smallest even 2^a 3^b 5^c >= n (a fast real-FFT length)."""
    best = 1 << max(1, math.ceil(math.log2(n)))
    p3 = 1
    while p3 < 2 * n:
        p5 = p3
        while p5 < 2 * n:
            v = p5 * 2
            while v < n:
                v *= 2
            best = min(best, v)
            p5 *= 5
        p3 *= 3
    return best


def ir_sampling(
    frequencies: npt.ArrayLike, max_delay: float = DEFAULT_MAX_DELAY
) -> tuple[float, int, int]:
    """Sampling of the impulse responses made from a frequency grid.

    Parameters
    ----------
    frequencies : array_like, Hz
        Uniform grid ``f_lo + k df`` of the transfer functions.
    max_delay : float, s
        Delay covered by the recorded samples (capped at the period ``1 / df``).

    Returns
    -------
    fs : float, Hz
        Equivalent sample rate ``N df`` (at least ``2.4 f_high``).
    n_fft : int
        Real-FFT length ``N``.
    n : int
        Samples kept per impulse response.
    """
    f = np.asarray(frequencies, float)
    df = float(f[1] - f[0])
    n_fft = _fast_length(math.ceil(OVERSAMPLING * f[-1] / df))
    fs = n_fft * df
    n = min(n_fft, math.ceil(max_delay * fs))
    return fs, n_fft, n


def frequency_to_ir(
    response: npt.NDArray[np.complexfloating],
    frequencies: npt.ArrayLike,
    n_fft: int,
    n: int,
) -> npt.NDArray[np.float32]:
    """Real impulse responses of band-limited ``1/d``-scaled transfer functions.

    .. math:: h[k] = \\frac{N}{2 \\sum_m w_m}\\,
              \\mathrm{irfft}_N\\big(w_m\\, H(f_m)\\, c / (4 \\pi f_m)\\big)[k],
              \\quad k < n

    with ``w`` a Hann window over the band and ``f_m = m df`` on the FFT grid.

    Parameters
    ----------
    response : ndarray, complex, shape (..., K)
        Transfer functions on ``frequencies`` (``1/d`` scale, as in ``RobotDataset``).
    frequencies : array_like, Hz, shape (K,)
        Uniform grid; ``f / df`` must be (close to) integers.
    n_fft, n : int
        From :func:`ir_sampling`.

    Returns
    -------
    ndarray, float32, shape (..., n)
        Sample ``k`` at ``k / (n_fft df)`` s after emission.
    """
    f = np.asarray(frequencies, float)
    df = float(f[1] - f[0])
    k0 = round(f[0] / df)
    if abs(f[0] / df - k0) > 1e-6 or k0 + f.size > n_fft // 2 + 1:
        raise ValueError("frequency grid does not fit the real-FFT grid")
    w = np.hanning(f.size + 2)[1:-1]  # no zero end points: every bin counts
    weight = (w * friis_amplitude(f) * n_fft / (2 * w.sum())).astype(np.complex64)
    spec = np.zeros((*response.shape[:-1], n_fft // 2 + 1), np.complex64)
    spec[..., k0 : k0 + f.size] = response * weight
    return np.fft.irfft(spec, n_fft, axis=-1)[..., :n].astype(np.float32)


@dataclass(frozen=True, slots=True, kw_only=True)
class OdometrySlip:
    """Noise of the robot's wheel odometry (standard deviations, SI units).

    Attributes
    ----------
    translation : float
        Per metre driven, m/m.
    rotation : float
        Per radian turned, rad/rad.
    heading_per_metre : float
        Heading error per metre driven (wheel slip on uneven floors), rad/m.
    floor : tuple of float
        Per acquisition, (m, rad).
    """

    translation: float = 0.02
    rotation: float = 0.03
    heading_per_metre: float = math.radians(1.0)
    floor: tuple[float, float] = (0.002, math.radians(0.1))


def odometry_increments(
    poses: npt.ArrayLike, rng: np.random.Generator | None = None, slip: OdometrySlip | None = None
) -> npt.NDArray[np.float64]:
    """Odometry ``(dx, dy, dyaw)`` of each acquisition since the previous one.

    The true increment in the previous robot frame, plus Gaussian slip noise whose standard
    deviation grows with the distance driven and the angle turned (``slip``); no noise when
    ``rng`` is None. The first row is zero.

    Parameters
    ----------
    poses : array_like, shape (k, 3) or (k, 4)
        ``[x, y, yaw]`` or ``[x, y, z, yaw]`` of consecutive acquisitions (m, rad).

    Returns
    -------
    ndarray, float64, shape (k, 3)
    """
    p = np.asarray(poses, float)
    xy, yaw = p[:, :2], p[:, -1]
    d = np.diff(xy, axis=0)
    c, s = np.cos(yaw[:-1]), np.sin(yaw[:-1])
    dyaw = (np.diff(yaw) + np.pi) % (2 * np.pi) - np.pi
    inc = np.column_stack([c * d[:, 0] + s * d[:, 1], -s * d[:, 0] + c * d[:, 1], dyaw])
    if rng is not None and inc.size:
        sl = slip or OdometrySlip()
        dist = np.hypot(inc[:, 0], inc[:, 1])
        s_tr = sl.translation * dist + sl.floor[0]
        s_rot = sl.rotation * np.abs(dyaw) + sl.heading_per_metre * dist + sl.floor[1]
        inc = inc + rng.normal(size=inc.shape) * np.column_stack([s_tr, s_tr, s_rot])
    return np.vstack([np.zeros((1, 3)), inc])


def robot_node_info(scenario: Scenario, radar: RadarInfo, pose: tuple[float, ...]) -> NodeInfo:
    """The robot's ``node_info``: antennas in the node frame (x forward, y left, z up)."""
    rb = scenario.robot
    if rb is None:
        raise ValueError(f"scenario {scenario.name!r} has no [robot]")
    bw = 2 * math.pi if rb.pattern == "omni" else float(rb.beamwidth)
    half = 0.5 * rb.baseline
    antennas = {
        TX: Antenna(pos=(0.0, 0.0, rb.height), tx=True, rx=False, boresight=0.0, beamwidth=bw),
        RX1: Antenna(pos=(0.0, half, rb.height), tx=False, rx=True, boresight=0.0, beamwidth=bw),
        RX2: Antenna(pos=(0.0, -half, rb.height), tx=False, rx=True, boresight=0.0, beamwidth=bw),
    }
    return NodeInfo(
        src=rb.id,
        seq=0,
        t=0.0,
        role="robot",
        pose=tuple(float(v) for v in pose),
        mobile=True,
        antennas=antennas,
        radar=radar,
    )


def write_robot_recording(
    scenario: Scenario,
    dataset: RobotDataset,
    out: str | os.PathLike[str],
    *,
    seed: int,
    snr_db: float = DEFAULT_SNR_DB,
    max_delay: float = DEFAULT_MAX_DELAY,
    net: str = "demo",
    progress: Callable[[int], None] | None = None,
    slip: OdometrySlip | None = None,
) -> int:
    """Write ``dataset`` (every stop and heading of ``scenario``'s robot) as a recording.

    Acquisition ``i`` (stop-major, then heading) is at ``t = i / radar.rate``; ``frame`` is
    ``i`` and ``slot`` 0. Every ``ir`` carries ``odom``, the wheel odometry since the previous
    acquisition with ``slip`` noise (:func:`odometry_increments`, drawn from
    ``default_rng([seed, 1])``). ``progress`` is called with the number of acquisitions written.
    Returns the number of messages written; ``out`` appears only when complete.
    """
    rb = scenario.robot
    if rb is None:
        raise ValueError(f"scenario {scenario.name!r} has no [robot]")
    f = dataset.frequencies
    fs, n_fft, n = ir_sampling(f, max_delay)
    rate = float(scenario.radar.rate)
    radar = RadarInfo(fs=fs, n=n, t0=0.0, f_low=float(f[0]), f_high=float(f[-1]), rate=rate)
    resp = dataset.response
    # Mean in-band power over the whole recording, the SNR reference (module docstring).
    power = float(np.mean(np.abs(resp) ** 2, dtype=np.float64))
    sigma = math.sqrt(power / 10 ** (snr_db / 10) / 2)  # per real and imaginary part
    poses = [
        [(float(x), float(y), 0.0, float(h)) for h in heads]
        for (x, y), heads in zip(dataset.stops, dataset.headings, strict=True)
    ]
    flat = [q for stop in poses for q in stop]
    odom = odometry_increments(flat, np.random.default_rng([seed, 1]), slip)
    ir_key = keys.node_key(net, rb.id, "ir")
    truth_key = keys.truth_key(net)
    with RecordingWriter(out) as rec:
        info = robot_node_info(scenario, radar, poses[0][0] if poses else (0.0, 0.0, 0.0, 0.0))
        rec.write_message(keys.node_key(net, rb.id, "info"), info)
        i = 0
        for s in range(resp.shape[0]):
            rng = np.random.default_rng([seed, s])
            noise = rng.normal(0.0, sigma, (*resp[s].shape, 2)).astype(np.float32)
            h = frequency_to_ir(resp[s] + noise.view(np.complex64)[..., 0], f, n_fft, n)
            for j, pose in enumerate(poses[s]):
                t = i / rate
                ir = Ir(
                    src=rb.id,
                    seq=i,
                    t=t,
                    tx=f"{rb.id}/{TX}",
                    rx=(RX1, RX2),
                    slot=0,
                    frame=i,
                    h=h[j],
                    pose=pose,
                    odom=(float(odom[i, 0]), float(odom[i, 1]), float(odom[i, 2])),
                )
                rec.write_message(ir_key, ir)
                rec.write_message(
                    truth_key, Truth(src="sim", seq=i, t=t, targets=(), nodes={rb.id: pose})
                )
                i += 1
            if progress is not None:
                progress(len(poses[s]))
        return rec.count
