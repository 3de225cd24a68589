"""The node's DSP chain: impulse responses in, ranges and local positions out (Section 9)."""

from __future__ import annotations

import bisect
import itertools
import math
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from .association import RangePairAssociator, pairing_threshold
from .background import ExponentialBackgroundSubtractor
from .band_filter import BandMatchedFilter
from .cfar import GaussianCfarDetector
from .ellipse import EllipseIntersector
from .geometry import WINDOW_GUARD, RadarParams, SensorGeometry
from .integration import NoncoherentIntegrator, integration_frames, merge_detections
from .range_phd import RangeGmPhdFilter

FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True, kw_only=True)
class NodeDspConfig:
    """Every parameter of the node DSP chain, declared once.

    Attributes
    ----------
    background_alpha : float
        Forgetting factor of the exponential background average; time constant
        ``1/alpha`` impulse responses (0.05: 0.4 s at 50 IR/s).
    noise_alpha : float
        Forgetting factor of the CFAR per-bin noise mean/variance averages.
    noise_censor : float
        Fraction of ``noise_alpha`` used in bins that cross the threshold.
    noise_clip_sigma : float
        Squared deviations enter the CFAR's variance average clipped at this many standard
        deviations (:class:`GaussianCfarDetector` ``clip_sigma``).
    pfa : float
        CFAR false-alarm probability per range sample. 1e-3 rather than a stricter value:
        far people's echoes sit only 3-4 noise standard deviations high, and the false alarms
        this lets through are cleaned by the range GM-PHD and by the fusion center, which
        weighs each estimate by how many sensors confirm it.
    min_range_guard : float
        Ranges shorter than the direct path Tx->Rx plus this guard (m) are ignored:
        residuals of the strong coupling live there.
    max_range : float or None
        Longest range processed, m; None processes the whole window. Shorter is faster.
    window_guard : float
        Ranges within this many pulse widths (``c / bandwidth``) of either end of the
        impulse response's window are not searched (:meth:`RadarParams.measurable`). An
        echo whose peak lies before the window start (a cropped window, ``t0 > 0``) or after
        its end leaves only a flank inside it: the detection sits at the window edge
        whatever the true range, on both receivers, and the ellipse intersection puts the
        person on the boresight at half the window's start range. 0 (off) by default, see
        ``WINDOW_GUARD``; with a guard, set ``FusionCoreConfig.blind_zone`` too.
    range_std : float
        Standard deviation of an estimated range, m (PHD measurement noise, and the
        position covariance).
    range_offset : float
        Added to every estimated range before the ellipse intersection, m. A person is
        not a point: the echo comes from the side of the body facing the antennas, so
        each leg of the bistatic path is shorter than to the body's centre by about the
        body's radius :math:`\\rho`, and the range by about :math:`2 \\rho
        \\cos(\\beta / 2) \\approx 2 \\rho` for the small bistatic angles :math:`\\beta`
        of a bat sensor. A torso is about 0.25-0.3 m deep and 0.45 m wide, an effective
        :math:`\\rho` of about 0.15 m: 0.3 m moves the intersections to body centres,
        which the fusion centre tracks (on the foyer3 simulation the median distance of
        positions to the truth falls from 0.21 m to 0.11 m). 0 for point scatterers.
    pairing_margin : float
        Margin added to the receiver baseline in the pairing threshold T_s, m.
    pairing_rate_std : float
        Allowed difference of one person's range rates at the two receivers, m/s
        (see :class:`RangePairAssociator`).
    pairing_log_amplitude_std : float
        Allowed difference of one person's log echo amplitudes at the two receivers.
    fov_margin : float
        Angle added to half the beamwidth when keeping ellipse intersections, rad.
    rx_pair : tuple of int or None
        Receivers whose ranges are intersected; None uses (0, 1) for two receivers and
        the pair with the longest baseline for more.
    process_noise : float
        Range acceleration spectral density of the range GM-PHD, m^2/s^3.
    detection_probability, survival_probability : float
        :math:`p_D`, :math:`p_S` of the range GM-PHD.
    clutter_rate : float or None
        Expected false detections per receiver and impulse response; None derives it
        from ``pfa`` and the window length.
    birth_weight : float
        Weight of a GM-PHD birth at an unexplained detection.
    birth_rate_std : float
        Range-rate standard deviation of a birth, m/s.
    cluster_gap : float
        Detections of one receiver closer than this (m) are one extended echo.
    prune_threshold, merge_threshold : float
        GM-PHD pruning weight and squared Mahalanobis merging gate.
    max_components : int
        Cap on GM-PHD components over all receivers.
    band_filter_min_gain_db : float or None
        Matched filtering to the declared band (:class:`BandMatchedFilter`) runs when its
        gain for the radar's sampling reaches this many dB (an oversampled complex
        baseband gains about 3 dB); None never filters.
    move_tolerance : float
        A new geometry whose antennas moved more than this (m), or turned more than
        ``move_tolerance`` rad, resets the background, the noise statistics and the range
        filter: every static echo changes range when the node moves.
    integration_range_rate : float
        Bistatic range rate (m/s) of a walker for the non-coherent integration
        (:class:`NoncoherentIntegrator`): the node sums the echo power of as many frames as
        such an echo takes to cross one pulse width (``c / bandwidth * rate /
        integration_range_rate``, from ``node_info.radar``) and adds the detections of that
        sum to the single-frame CFAR's. 2.5 m/s: a person walking at 1.25 m/s straight at a
        bat sensor (both legs of the path shorten). With it a narrow-band radar (1.2-1.4
        GHz at 30-40 frames/s: 3 frames) integrates, a wide-band one (3.5 GHz at 50/s) does
        not (1 frame: off, no cost). 0 turns it off (docs/integration.md).
    max_integration_frames : int
        Cap on the frames summed.
    """

    background_alpha: float = 0.05
    noise_alpha: float = 0.005
    noise_censor: float = 0.1
    noise_clip_sigma: float = 3.0
    pfa: float = 1e-3
    min_range_guard: float = 0.5
    max_range: float | None = None
    window_guard: float = WINDOW_GUARD
    range_std: float = 0.05
    range_offset: float = 0.3
    pairing_margin: float = 0.15
    pairing_rate_std: float = 0.3
    pairing_log_amplitude_std: float = 0.7
    fov_margin: float = 0.35
    rx_pair: tuple[int, int] | None = None
    process_noise: float = 0.5
    detection_probability: float = 0.8
    survival_probability: float = 0.99
    clutter_rate: float | None = None
    birth_weight: float = 0.1
    birth_rate_std: float = 2.0
    cluster_gap: float = 0.4
    prune_threshold: float = 1e-3
    merge_threshold: float = 4.0
    max_components: int = 60
    band_filter_min_gain_db: float | None = 1.0
    move_tolerance: float = 0.01
    integration_range_rate: float = 2.5
    max_integration_frames: int = 8


@dataclass(frozen=True, slots=True, kw_only=True, eq=False)
class DspResult:
    """Output of :meth:`NodeDsp.process` for one impulse-response matrix.

    Attributes
    ----------
    t : float
        Time of the impulse responses, s.
    ranges : tuple of ndarray, float64, shape (k_i,)
        Per receiver (row of ``h``), the estimated bistatic target ranges, m, ascending.
    amplitudes : tuple of ndarray, float64, shape (k_i,)
        Per receiver, the echo amplitudes (units of ``h``).
    positions : ndarray, float64, shape (k, 2)
        Local position estimates, world x, y, m (empty with one receiver).
    cov : ndarray, float64, shape (k, 2, 2)
        Their covariances, m^2.
    rx_pair : tuple of int or None
        The receivers whose ranges gave ``positions``.
    """

    t: float
    ranges: tuple[FloatArray, ...]
    amplitudes: tuple[FloatArray, ...]
    positions: FloatArray = field(default_factory=lambda: np.empty((0, 2)))
    cov: FloatArray = field(default_factory=lambda: np.empty((0, 2, 2)))
    rx_pair: tuple[int, int] | None = None


def _best_pair(geometry: SensorGeometry) -> tuple[int, int]:
    xy = geometry.rx[:, :2]
    dist = np.linalg.norm(xy[:, None] - xy[None, :], axis=2)
    i, j = np.unravel_index(np.argmax(np.triu(dist, 1)), dist.shape)
    return int(i), int(j)


class NodeDsp:
    """Background subtraction -> CFAR -> range GM-PHD -> pairing -> ellipse intersection.

    Parameters
    ----------
    geometry : SensorGeometry
        Antennas in the world frame; may be replaced per call for mobile nodes.
    radar : RadarParams
        Sampling of the impulse responses.
    config : NodeDspConfig
        Parameters; defaults when omitted.
    """

    def __init__(
        self,
        geometry: SensorGeometry,
        radar: RadarParams,
        config: NodeDspConfig | None = None,
    ) -> None:
        self.config = cfg = config if config is not None else NodeDspConfig()
        self.radar = radar
        self.n_rx = geometry.n_rx
        axis = radar.ranges()
        direct = geometry.direct_ranges()
        r_lo = float(np.min(direct)) + cfg.min_range_guard
        r_hi = float(axis[-1]) if cfg.max_range is None else float(cfg.max_range)
        # the whole chain runs on the window [r_lo, r_hi]: less work, no coupling
        self._i0 = int(np.searchsorted(axis, r_lo, side="left"))
        self._i1 = max(int(np.searchsorted(axis, r_hi, side="right")), self._i0)
        self._window = axis[self._i0 : self._i1]
        length = max(r_hi - r_lo, radar.range_step)
        clutter = cfg.clutter_rate
        if clutter is None:
            clutter = cfg.pfa * self._window.size + 0.1
        self._background = ExponentialBackgroundSubtractor(cfg.background_alpha)
        self._y: npt.NDArray | None = None
        self._cfar: GaussianCfarDetector | None = None
        self._integrator: NoncoherentIntegrator | None = None
        self._integration_frames = integration_frames(
            radar.pulse_range_width,
            radar.rate,
            cfg.integration_range_rate,
            cfg.max_integration_frames,
        )
        self._filter: BandMatchedFilter | None = None
        self._phd = RangeGmPhdFilter(
            n_channels=self.n_rx,
            range_std=cfg.range_std,
            process_noise=cfg.process_noise,
            detection_probability=cfg.detection_probability,
            survival_probability=cfg.survival_probability,
            clutter_intensity=clutter / length,
            birth_weight=cfg.birth_weight,
            birth_rate_std=cfg.birth_rate_std,
            cluster_gap=cfg.cluster_gap,
            prune_threshold=cfg.prune_threshold,
            merge_threshold=cfg.merge_threshold,
            max_components=cfg.max_components,
        )
        self._set_geometry(geometry)

    @property
    def geometry(self) -> SensorGeometry:
        """The current antenna geometry."""
        return self._geometry

    def _set_geometry(self, geometry: SensorGeometry) -> None:
        if geometry.n_rx != self.n_rx:
            raise ValueError(f"geometry has {geometry.n_rx} receivers, expected {self.n_rx}")
        self._geometry = geometry
        # neither the coupling residuals after the direct path nor an echo cut at the
        # window start
        lo, _ = self.radar.measurable(self.config.window_guard)
        self._min_range = np.maximum(geometry.direct_ranges() + self.config.min_range_guard, lo)
        if self._cfar is not None:
            self._cfar.set_min_range(self._min_range)
        if self.n_rx < 2:
            self._pair = None
            self._associator = None
            return
        pair = self.config.rx_pair if self.config.rx_pair is not None else None
        if pair is None:
            pair = (0, 1) if self.n_rx == 2 else _best_pair(geometry)
        i, j = pair
        self._pair = (int(i), int(j))
        threshold = pairing_threshold(
            geometry.rx[i, :2], geometry.rx[j, :2], self.config.pairing_margin
        )
        self._associator = RangePairAssociator(
            threshold, self.config.pairing_rate_std, self.config.pairing_log_amplitude_std
        )
        self._intersector = EllipseIntersector(geometry.tx, geometry.rx[i], geometry.rx[j])
        # the field-of-view test of SensorGeometry.in_field_of_view, with its constants
        # computed once: cos(bearing - boresight) >= cos(half beamwidth + margin)
        half = min(0.5 * geometry.beamwidth + self.config.fov_margin, np.pi)
        # (centre x, centre y, boresight x, boresight y, cos), floats for the scalar test
        cx, cy = np.asarray(geometry.centre, dtype=np.float64).ravel()[:2].tolist()
        self._fov = (cx, cy, float(np.cos(geometry.boresight)), float(np.sin(geometry.boresight)))
        self._fov_cos = float(np.cos(half))

    def reset(self) -> None:
        """Forget the background, the noise statistics and the range tracks."""
        self._background.reset()
        if self._cfar is not None:
            self._cfar.reset()
        if self._integrator is not None:
            self._integrator.reset()
        self._phd.reset()

    def _moved(self, geometry: SensorGeometry) -> bool:
        old, tol = self._geometry, self.config.move_tolerance
        shift = max(
            float(np.max(np.abs(geometry.tx - old.tx))),
            float(np.max(np.abs(geometry.rx - old.rx))),
        )
        turn = abs(np.angle(np.exp(1j * (geometry.boresight - old.boresight))))
        return shift > tol or turn > tol

    def _make_cfar(self, complex_input: bool) -> GaussianCfarDetector:
        return GaussianCfarDetector(
            self.config.pfa,
            ranges=self._window,
            pulse_width=self.radar.pulse_range_width,
            min_range=self._min_range,
            max_range=self.radar.measurable(self.config.window_guard)[1],
            alpha=self.config.noise_alpha,
            complex_input=complex_input,
            censor=self.config.noise_censor,
            clip_sigma=self.config.noise_clip_sigma,
        )

    def _make_filter(self, complex_input: bool) -> BandMatchedFilter | None:
        min_gain = self.config.band_filter_min_gain_db
        if min_gain is None:
            return None
        band = BandMatchedFilter(self.radar, complex_input=complex_input)
        return band if band.gain_db >= min_gain else None

    def process(
        self, t: float, h: npt.NDArray, geometry: SensorGeometry | None = None
    ) -> DspResult:
        """Run the chain on one impulse-response matrix.

        Parameters
        ----------
        t : float
            Network time of the acquisition, s.
        h : ndarray, float32 or complex64, shape (n_rx, n)
            Impulse responses; sample k at ``t0 + k/fs`` after emission.
        geometry : SensorGeometry, optional
            New antenna geometry (mobile node); the last one is kept when omitted.

        Returns
        -------
        DspResult
        """
        if h.ndim != 2 or h.shape[0] != self.n_rx or h.shape[1] != self.radar.n:
            raise ValueError(f"h has shape {h.shape}, expected ({self.n_rx}, {self.radar.n})")
        if geometry is not None and geometry is not self._geometry:
            if self._moved(geometry):
                self.reset()
            self._set_geometry(geometry)
        is_complex = h.dtype.kind == "c"
        if self._cfar is None or self._cfar.complex_input != is_complex:
            self._cfar = self._make_cfar(is_complex)
            self._filter = self._make_filter(is_complex)
            if self._integration_frames > 1:
                self._integrator = NoncoherentIntegrator(
                    self._integration_frames,
                    self.config.pfa,
                    ranges=self._window,
                    pulse_width=self.radar.pulse_range_width,
                    complex_input=is_complex,
                )
        window = h[:, self._i0 : self._i1]
        if self._y is None or self._y.shape != window.shape or self._y.dtype != window.dtype:
            self._y = np.empty(window.shape, dtype=window.dtype)
        # the subtracted frame lives only within this call: one buffer, no allocation
        detections = None
        if self._filter is None and not is_complex:
            # real samples, no band filter: background and CFAR in one compiled call, the
            # same bits (None until both have their state: the first frames go below)
            bg = self._background.state_for(window)
            if bg is not None:
                detections = self._cfar.detect_subtracting(
                    window, bg, self._background.alpha, self._y
                )
        if detections is not None:
            y = self._y
        else:
            y = self._background.step(window, out=self._y)
            if self._filter is not None:
                y = self._filter.apply(y)
            # estimate rows (rate variance, range, rate, amplitude, channel), by channel
            detections = self._cfar.detect(y)
        if self._integrator is not None:
            noise = self._cfar.noise_power()
            if noise is not None:
                detections = merge_detections(
                    detections,
                    self._integrator.step(y, *noise),
                    self.radar.pulse_range_width,
                )
        est = self._phd.step_detections(t, *detections)
        # a handful of estimates: the rest of the chain is scalar arithmetic on Python
        # floats, which beats numpy calls on 1-5 element arrays
        rows = est.tolist()
        chans = [row[4] for row in rows]
        bounds = [bisect.bisect_left(chans, c - 0.5) for c in range(self.n_rx + 1)]
        spans = list(itertools.pairwise(bounds))
        ranges = tuple(est[a:b, 1] for a, b in spans)
        amps = tuple(est[a:b, 3] for a, b in spans)
        if self._pair is None or self._associator is None:
            return DspResult(t=t, ranges=ranges, amplitudes=amps)
        i, j = self._pair
        rows1, rows2 = rows[slice(*spans[i])], rows[slice(*spans[j])]
        r1 = [row[1] for row in rows1]
        r2 = [row[1] for row in rows2]
        k1, k2 = self._associator.associate_lists(
            r1, r2, [(v, d, a) for v, _, d, a, _ in rows1], [(v, d, a) for v, _, d, a, _ in rows2]
        )
        if not k1:
            return DspResult(t=t, ranges=ranges, amplitudes=amps, rx_pair=self._pair)
        off = self.config.range_offset
        located = self._intersector.locate(
            [r1[k] + off for k in k1], [r2[k] + off for k in k2], self.config.range_std
        )
        # field of view: cos(bearing - boresight) >= cos(half beamwidth + margin)
        cx, cy, dx, dy = self._fov
        fov_cos = self._fov_cos
        kept = [
            p
            for p in located
            if (p[0] - cx) * dx + (p[1] - cy) * dy >= math.hypot(p[0] - cx, p[1] - cy) * fov_cos
        ]
        if not kept:
            return DspResult(t=t, ranges=ranges, amplitudes=amps, rx_pair=self._pair)
        return DspResult(
            t=t,
            ranges=ranges,
            amplitudes=amps,
            positions=np.array([(x, y) for x, y, _, _, _ in kept]),
            cov=np.array([((a, b), (b, c)) for _, _, a, b, c in kept]),
            rx_pair=self._pair,
        )
