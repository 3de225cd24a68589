"""LOS/NLOS identification of one link from the shape of one impulse response.

Beyond the chapter, whose NLOS test (eq. (6)) needs several ranges of a static node: here a
single impulse response decides, from features of its envelope (after matched filtering to
the band, :mod:`node_agent.dsp.band_filter`), in physical units so that the decision does not
depend on the sample rate, band, window or amplitude scale of the radar:

* ``fp_to_peak_db``: first path over strongest path, dB (:math:`\\le 0`). An obstructed
  direct path (wall, furniture, body: 5-20 dB of loss) arrives weaker than the reflections
  that go around the obstacle.
* ``rise_time``: delay from the first path to the strongest, ns. Near 0 in LOS; in NLOS the
  strongest energy comes with the multipath, several ns later.
* ``mean_excess_delay`` and ``rms_delay_spread``: first and second central moment of the
  power delay profile after the first path, ns (eq. 2.3-2.4 of Molisch, "Wireless
  Communications"). NLOS energy is spread later and wider.
* ``fp_energy_db``: energy within one pulse width of the first path over the energy of
  the profile, dB.
* ``kurtosis`` of the envelope over the profile window: one dominant path (LOS) makes a
  peaky, heavy-tailed amplitude distribution.
* ``early_energy_db``: energy up to ``early`` (10 ns) after the first path over the energy
  of the profile, dB: the share of the first cluster (the direct path and the reflections
  of the nearest surfaces), which an obstacle on the direct path takes away.
* ``median_excess_delay``: delay after the first path by which half the profile's energy has
  arrived, ns; the mean excess delay's robust counterpart (one strong late cluster moves it
  less).

The profile is the envelope power with the noise power removed, :math:`\\max(e^2 - 2
\\sigma^2, 0)`, counted only where the envelope exceeds :math:`4 \\sigma` (complex noise
alone does so once in about 3000 samples) and within ``window`` after the first path, so that
noise adds neither delay spread nor energy.

:class:`LogisticNlosClassifier` combines the features linearly; its default coefficients
were fitted by :mod:`uwbnet.nlos_training` on stochastic 802.15.4a-type LOS and NLOS channels
(:mod:`sim_nodes.channel.stochastic`) rendered through several radars, never on measured data.
"""

from __future__ import annotations

import tomllib
from collections.abc import Callable
from dataclasses import dataclass
from importlib import resources

import numpy as np
import numpy.typing as npt

FloatArray = npt.NDArray[np.float64]

FEATURES = (
    "fp_to_peak_db",
    "rise_time",
    "mean_excess_delay",
    "rms_delay_spread",
    "fp_energy_db",
    "kurtosis",
    "early_energy_db",
    "median_excess_delay",
)
"""Feature names, in the column order of :func:`channel_features`."""


def channel_features(
    env: FloatArray,
    sigma: FloatArray,
    first: FloatArray,
    *,
    fs: float,
    bandwidth: float,
    window: float = 100e-9,
    early: float = 10e-9,
) -> FloatArray:
    """Shape features of each envelope row, see the module docstring.

    Parameters
    ----------
    env : ndarray, float64, shape (rows, n)
        Envelopes (after matched filtering).
    sigma : ndarray, float64, shape (rows,)
        Noise :math:`\\sigma` of each envelope (per component, Rayleigh parameter).
    first : ndarray, float64, shape (rows,)
        Fractional sample index of the first path; NaN where none was found.
    fs : float
        Sample rate, Hz.
    bandwidth : float
        Band occupied, Hz: one pulse width is ``1 / bandwidth``.
    window : float
        Length of the profile after the first path, s.
    early : float
        End of the early part of the profile after the first path, s (``early_energy_db``).

    Returns
    -------
    ndarray, float64, shape (rows, len(FEATURES))
        Columns as in :data:`FEATURES`: dB, ns, ns, ns, dB, dimensionless, dB, ns. NaN rows
        where ``first`` is NaN. A row with a first path but an empty profile (no sample of
        the window above :math:`4 \\sigma`) is not NaN: its energy ratios
        (``fp_energy_db``, ``early_energy_db``) are 0 dB (0/0 taken as 1) and its delays
        (``mean_excess_delay``, ``rms_delay_spread``, ``median_excess_delay``) 0 ns, the
        values of a lone direct path. Callers that pass a ``first`` not detected above the
        noise should set it to NaN (``uwbnet ranging`` passes NaN where its detector found
        nothing).
    """
    rows, n = env.shape
    r = np.arange(rows)
    ok = np.isfinite(first)
    k_fp = np.clip(np.where(ok, np.rint(first), 0).astype(np.intp), 0, n - 1)
    k_pk = np.argmax(env, axis=1)
    a_fp = env[r, k_fp]
    a_pk = env[r, k_pk]
    fp_to_peak = 20.0 * np.log10(np.maximum(a_fp, 1e-300) / np.maximum(a_pk, 1e-300))
    t_ns = 1e9 / fs
    rise = np.maximum(k_pk - np.where(ok, first, 0.0), 0.0) * t_ns

    pulse = max(1, int(np.ceil(fs / bandwidth)))
    span = max(1, int(np.ceil(window * fs)))
    cols = np.arange(n)[None, :]
    rel = cols - np.where(ok, first, 0.0)[:, None]  # samples after the first path
    in_win = (rel >= -pulse) & (rel <= span)
    s2 = (sigma * sigma)[:, None]
    p = np.where(in_win & (env > 4.0 * sigma[:, None]), np.maximum(env * env - 2.0 * s2, 0.0), 0)
    total = np.maximum(p.sum(axis=1), 1e-300)
    tau = np.maximum(rel, 0.0) * t_ns
    mean_delay = (p * tau).sum(axis=1) / total
    spread = np.sqrt(np.maximum((p * tau * tau).sum(axis=1) / total - mean_delay**2, 0.0))
    near = np.abs(rel) <= pulse
    fp_energy = 10.0 * np.log10(np.maximum((p * near).sum(axis=1), 1e-300) / total)

    # kurtosis of the envelope over the window (noise included: the window is fixed in time)
    cnt = np.maximum(in_win.sum(axis=1), 1)
    e = np.where(in_win, env, 0.0)
    mu = e.sum(axis=1) / cnt
    d = np.where(in_win, env - mu[:, None], 0.0)
    m2 = (d * d).sum(axis=1) / cnt
    m4 = (d**4).sum(axis=1) / cnt
    kurt = m4 / np.maximum(m2 * m2, 1e-300)

    early_energy = 10.0 * np.log10(
        np.maximum((p * (rel <= early * fs)).sum(axis=1), 1e-300) / total
    )
    # first sample at which the cumulative profile reaches half the energy
    half = np.argmax(np.cumsum(p, axis=1) >= 0.5 * total[:, None], axis=1)
    median_delay = tau[r, half]

    out = np.column_stack(
        [fp_to_peak, rise, mean_delay, spread, fp_energy, kurt, early_energy, median_delay]
    )
    out[~ok] = np.nan
    return out


@dataclass(frozen=True, slots=True, kw_only=True)
class LogisticNlosClassifier:
    """NLOS if the logistic score of standardised features is positive.

    .. math::

        P(\\mathrm{NLOS} \\mid x) = \\frac{1}{1 + \\exp(-(b + \\sum_i w_i (x_i - m_i) / s_i))}

    with features :math:`x_i` as in :func:`channel_features`, clipped to physical ranges
    (``clip``) so that one extreme feature cannot outvote the others. A row without a first
    path (nothing above the noise) is NLOS.

    Attributes
    ----------
    features : tuple of str
        Names (from :data:`FEATURES`) used, in the order of the weights.
    mean, scale : tuple of float
        Standardisation :math:`m_i`, :math:`s_i` (units of the features).
    weights : tuple of float
        :math:`w_i`.
    bias : float
        :math:`b`.
    clip : tuple of (float, float)
        Per feature, the range its value is clipped to before scoring.

    Raises
    ------
    ValueError
        On unequal lengths, unknown feature names, a scale that is not finite and > 0, a
        mean, weight or bias that is not finite, or a clip range without ``lo < hi``.
    """

    features: tuple[str, ...]
    mean: tuple[float, ...]
    scale: tuple[float, ...]
    weights: tuple[float, ...]
    bias: float
    clip: tuple[tuple[float, float], ...]

    def __post_init__(self) -> None:
        k = len(self.features)
        if not (len(self.mean) == len(self.scale) == len(self.weights) == len(self.clip) == k):
            raise ValueError("features, mean, scale, weights and clip must have equal lengths")
        unknown = set(self.features) - set(FEATURES)
        if unknown:
            raise ValueError(f"unknown features {sorted(unknown)}")
        # a NaN or zero scale makes every score NaN or infinite: every row silently NLOS
        if not all(np.isfinite(v) and v > 0.0 for v in self.scale):
            raise ValueError(f"scale must be finite and > 0, got {self.scale}")
        if not np.all(np.isfinite([*self.mean, *self.weights, self.bias])):
            raise ValueError("mean, weights and bias must be finite")
        if not all(lo < hi for lo, hi in self.clip):
            raise ValueError(f"each clip range must have lo < hi, got {self.clip}")

    def score(self, x: FloatArray) -> FloatArray:
        """Logit of NLOS, shape (rows,), from features ``x`` (rows, len(FEATURES))."""
        cols = [FEATURES.index(f) for f in self.features]
        lo, hi = np.array(self.clip, dtype=np.float64).T
        z = (np.clip(x[:, cols], lo, hi) - np.array(self.mean)) / np.array(self.scale)
        s = self.bias + z @ np.array(self.weights)
        return np.where(np.all(np.isfinite(x[:, cols]), axis=1), s, np.inf)

    def nlos_probability(self, x: FloatArray) -> FloatArray:
        """:math:`P(\\mathrm{NLOS} \\mid x)`, shape (rows,)."""
        return 1.0 / (1.0 + np.exp(-self.score(x)))

    def is_los(self, x: FloatArray) -> npt.NDArray[np.bool_]:
        """LOS decision of each row, shape (rows,)."""
        return self.score(x) < 0.0


MODEL_FORMAT = 1
"""Format version of the classifier files :func:`load_classifier` reads."""

DEFAULT_MODEL = "nlos_model.toml"
"""The packaged default classifier (``node_agent/dsp/nlos_model.toml``)."""


def _is_number(v: object) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


def _list_of(d: dict, key: str, check: Callable[[object], bool], what: str) -> list:
    v = d.get(key)
    if not isinstance(v, list) or not all(check(a) for a in v):
        raise ValueError(f"classifier {key} must be a list of {what}, got {v!r}")
    return v


def classifier_from_dict(d: dict) -> LogisticNlosClassifier:
    """:class:`LogisticNlosClassifier` from a parsed model file (keys as in
    ``nlos_model.toml``: ``format``, ``version``, ``kind`` and the class's fields).

    Raises
    ------
    ValueError
        One line, on another format version or kind, a ``version`` that is not an integer
        >= 1, a missing field or one of the wrong type (a string where a list belongs), or
        inconsistent coefficients (see :class:`LogisticNlosClassifier`).
    """
    if d.get("format") != MODEL_FORMAT:
        raise ValueError(f"classifier format {d.get('format')!r}, expected {MODEL_FORMAT}")
    if d.get("kind") != "logistic":
        raise ValueError(f"classifier kind {d.get('kind')!r}, expected 'logistic'")
    version = d.get("version")
    if not (isinstance(version, int) and not isinstance(version, bool) and version >= 1):
        raise ValueError(f"classifier version must be an integer >= 1, got {version!r}")
    features = _list_of(d, "features", lambda a: isinstance(a, str), "feature names")
    mean = _list_of(d, "mean", _is_number, "numbers")
    scale = _list_of(d, "scale", _is_number, "numbers")
    weights = _list_of(d, "weights", _is_number, "numbers")
    clip = _list_of(
        d,
        "clip",
        lambda a: isinstance(a, list) and len(a) == 2 and all(_is_number(b) for b in a),
        "[lo, hi] pairs",
    )
    bias = d.get("bias")
    if not _is_number(bias):
        raise ValueError(f"classifier bias must be a number, got {bias!r}")
    return LogisticNlosClassifier(
        features=tuple(features),
        mean=tuple(float(v) for v in mean),
        scale=tuple(float(v) for v in scale),
        weights=tuple(float(v) for v in weights),
        bias=float(bias),
        clip=tuple((float(a), float(b)) for a, b in clip),
    )


def load_classifier(name: str = DEFAULT_MODEL) -> tuple[LogisticNlosClassifier, int]:
    """The classifier packaged as ``node_agent/dsp/NAME`` and its model ``version``.

    Package data, read once at import for :data:`DEFAULT_CLASSIFIER`; no user file is read
    here (the core stays free of I/O of its own)."""
    text = resources.files(__package__).joinpath(name).read_text(encoding="utf-8")
    d = tomllib.loads(text)
    return classifier_from_dict(d), d["version"]


# The default was fitted by ``python -m uwbnet.nlos_training`` (training seed 1: 250 channels
# per class and radar, residential and office LOS and NLOS classes, four radars; features
# ``SELECTED`` there). On those simulated channels it is right 80 % of the time, 77 % on
# held-out ones (seed 2, other radars, other decay constants); the best single feature (mean
# excess delay) 78 % and 74 %. Leave-one-environment-out (``python -m uwbnet.nlos_loeo``,
# docs/localization.md): no variant is clearly better in the mean, and none is good; on the
# industrial environment (unchecked CM7/CM8 figures) it is near chance. The signs are the
# physical ones: a weaker, earlier first path, later energy and a flatter profile mean NLOS.
DEFAULT_CLASSIFIER, DEFAULT_MODEL_VERSION = load_classifier()
"""The simulator-trained default rule of ``uwbnet ranging`` and its model version."""
