"""Round-trip ToA (RTToA) ranging between unsynchronised nodes (Section 2.1 of the CoLOR chapter).

Two nodes with free-running clocks range by exchanging pulses: node A sends a poll, B replies
after a delay measured on its own clock, and A measures the round trip on its own. Clock
offsets cancel because each node only measures time differences on its own clock. The
single-sided form of the chapter,

.. math:: \\hat\\tau = \\frac{R_A - D_B}{2},

keeps an error :math:`\\tfrac12 D_B (e_A - e_B)` from the clocks' drift (20 ppm over a 1 ms
reply is 3 m of range); the double-sided form (a third message, A's reply delay :math:`D_A`
and B's round trip :math:`R_B`; Neirynck et al., IEEE WPNC 2016, beyond the chapter)

.. math:: \\hat\\tau = \\frac{R_A R_B - D_A D_B}{R_A + R_B + D_A + D_B}

cancels it to first order for any reply delays. Every receive timestamp is the receiver's
window start plus the first-path ToA found in that window's impulse response by
:class:`~node_agent.dsp.ranging.FirstPathRanger`, so the ranging inherits its estimator (MPD,
thresholds, peak) and its per-impulse-response LOS/NLOS decision.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from .geometry import SPEED_OF_LIGHT, RadarParams
from .ranging import FirstPathRanger

FloatArray = npt.NDArray[np.float64]

#: Floor of the reported range standard deviation, m. The reported std is the noise core's
#: (the per-reception ToA bound at the first path's SNR), which the fusion center's robust
#: tracker gates against; multipath outliers are its business, not this floor's (it was 5 mm,
#: ten times the core on the 7 GHz radar, which hid every millimetre outlier).
MIN_RANGE_STD = 1e-4


def single_sided_tof(round_a: float, reply_b: float) -> float:
    """Time of flight from single-sided two-way ranging, s (eq. of Section 2.1)."""
    return 0.5 * (round_a - reply_b)


def double_sided_tof(round_a: float, reply_a: float, round_b: float, reply_b: float) -> float:
    """Time of flight from asymmetric double-sided two-way ranging, s (drift-tolerant)."""
    return (round_a * round_b - reply_a * reply_b) / (round_a + round_b + reply_a + reply_b)


@dataclass(frozen=True, slots=True, kw_only=True, eq=False)
class RoundTrip:
    """What the two radios of one RTToA exchange measured, each on its own clock.

    Attributes
    ----------
    tx_times : ndarray, shape (m,)
        Local emission time of message k on its sender's clock, s (m = 2 single-sided, 3
        double-sided; message 0 from A, 1 from B, 2 from A).
    window_starts : ndarray, shape (m,)
        Local time of sample 0 of the receive window of message k on its receiver's clock, s.
    h : ndarray, shape (m, n)
        Impulse response recorded in each receive window (float32 or complex64).
    """

    tx_times: FloatArray
    window_starts: FloatArray
    h: npt.NDArray


@dataclass(frozen=True, slots=True, kw_only=True)
class LinkMeasurement:
    """One node-to-node range: ``range`` and ``std`` in m, ``los`` (per impulse response,
    all receptions LOS), ``snr_db`` the weakest reception's first-path SNR."""

    range: float
    std: float
    los: bool
    snr_db: float


class RoundTripRanger:
    """Range from one RTToA exchange.

    Parameters
    ----------
    radar : RadarParams
        The ranging radio's sampling and band (``t0`` is ignored: the window start is given).
    method : str
        ToA estimator of the receive timestamps (:func:`~node_agent.dsp.toa.make_toa_estimator`).
    """

    def __init__(self, radar: RadarParams, method: str = "adaptive") -> None:
        self.radar = radar
        self.ranger = FirstPathRanger(radar, method=method)
        # RMS bandwidth of the band's envelope (flat spectrum): B / sqrt(12)
        self._beta = (radar.f_high - radar.f_low) / math.sqrt(12.0)

    def measure(self, rt: RoundTrip) -> LinkMeasurement:
        """Range (first-path distance, m) of one exchange; NaN if a first path was missed."""
        res = self.ranger.process(rt.h)
        rx = rt.window_starts + res.toa
        m = rt.tx_times.size
        round_a = rx[1] - rt.tx_times[0]
        reply_b = rt.tx_times[1] - rx[0]
        if m >= 3:
            round_b = rx[2] - rt.tx_times[1]
            reply_a = rt.tx_times[2] - rx[1]
            tof = double_sided_tof(round_a, reply_a, round_b, reply_b)
            # tof error = (e0 + 2 e1 + e2) / 4 for receive-timestamp errors e_k
            weights = np.array([0.25, 0.5, 0.25])
        else:
            tof = single_sided_tof(round_a, reply_b)
            weights = np.array([0.5, 0.5])
        snr = np.asarray(res.snr_db, float)
        # per-reception ToA bound at the first path's SNR (peak over noise sigma, taken as the
        # energy SNR of one sample: conservative for a pulse spanning several samples)
        sig_t = 1.0 / (2.0 * math.pi * self._beta * np.sqrt(2.0 * 10.0 ** (snr / 10.0)))
        std = SPEED_OF_LIGHT * float(np.sqrt(np.sum((weights * sig_t) ** 2)))
        ok = np.all(np.isfinite(res.toa))
        return LinkMeasurement(
            range=SPEED_OF_LIGHT * tof if ok else float("nan"),
            std=max(std, MIN_RANGE_STD) if ok else float("inf"),
            los=bool(np.all(res.los)),
            snr_db=float(np.min(snr)) if snr.size else float("nan"),
        )
