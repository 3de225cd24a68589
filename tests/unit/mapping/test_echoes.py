"""Echo extraction and pairing on synthetic passband impulse responses."""

from __future__ import annotations

import numpy as np

from fusion_center.mapping.echoes import (
    C,
    EchoSet,
    EnvelopePeakEchoExtractor,
    analytic_envelope,
    pair_echoes,
)

FS, B, F0 = 32.4e9, 8.9e9, 8.95e9


def _pulse_ir(ranges: list[float], amps: list[float], n: int = 3240) -> np.ndarray:
    t = np.arange(n) / FS
    h = np.zeros(n)
    for r, a in zip(ranges, amps, strict=True):
        tau = t - r / C
        h += (
            a
            * np.exp(-0.5 * (tau * B / 2.5) ** 2 * (2 * np.pi) ** 2 / 4)
            * np.cos(2 * np.pi * F0 * tau)
        )
    return h


def test_analytic_envelope_peaks_at_the_pulse() -> None:
    h = _pulse_ir([3.0], [1.0])
    k = int(np.argmax(analytic_envelope(h[None])[0]))
    assert abs(C * k / FS - 3.0) < C / FS


def test_extractor_finds_echoes_within_a_centimetre(rng: np.random.Generator) -> None:
    ex = EnvelopePeakEchoExtractor(fs=FS, bandwidth=B, warmup=0, dynamic_db=20.0)
    truth = ([2.5, 4.2, 7.9], [2.9, 4.1, 8.3])
    h = np.stack([_pulse_ir(r, [1.0, 0.6, 0.4]) for r in truth])
    h += rng.normal(0.0, 0.01, h.shape)
    (echoes,) = ex.push(h.astype(np.float32))
    for j in range(2):
        assert echoes.ranges[j].size == 3
        assert np.max(np.abs(echoes.ranges[j] - truth[j])) < 0.01
    z = pair_echoes(echoes)
    assert np.allclose(z, np.column_stack(truth), atol=0.01)


def test_median_background_removes_robot_fixed_echoes(rng: np.random.Generator) -> None:
    ex = EnvelopePeakEchoExtractor(fs=FS, bandwidth=B, warmup=8)
    fixed = _pulse_ir([2.06], [3.0])  # the floor: the same in every acquisition
    out = []
    for k in range(10):
        moving = _pulse_ir([3.0 + 0.2 * k], [1.0])
        h = np.stack([fixed + moving, fixed + moving]) + rng.normal(0, 0.01, (2, 3240))
        out += ex.push(h.astype(np.float32))
    assert len(out) == 10
    for k, e in enumerate(out):
        assert e.ranges[0].size == 1 and abs(e.ranges[0][0] - (3.0 + 0.2 * k)) < 0.01


def test_pairing_respects_the_gate() -> None:
    e = EchoSet(ranges=(np.array([3.0]), np.array([4.0])), amplitudes=(np.ones(1), np.ones(1)))
    assert pair_echoes(e, max_difference=0.6).shape == (0, 2)
