"""The Section 7 chain on one recorded circular scan: wavefronts, contour, material, class.

Input: the impulse responses of every scan position in the V/V, H/H, V/H and 45-degree
channels, the sensor poses and antenna geometry. Steps:

1. **Reference pulse**: the strongest echo of the scan (a face at normal incidence: one
   clean pulse), cut out of the VV channel: a self-calibration in place of a calibration
   plate.
2. **Wavefronts**: per position, Wiener deconvolution (eq. (15),
   :class:`node_agent.dsp.deconvolution.WienerDeconvolver`) of the co-polar sum and pulse
   separation by the Dynamic Correlation Method (:mod:`.pulses`) in the range gate of the
   track; echoes more than ``dynamic_range_db`` below the scan's strongest are dropped.
3. **Contour**: fuzzy RPM imaging (:mod:`.fuzzy`) with the bistatic range ellipses of the
   Tx/Rx pair (not the boresight conversion to a monostatic distance, which a wide baseline
   breaks off the boresight).
4. **Polarimetry and material**: depolarization ``P_VH / P_VV`` around the first wavefront;
   corner points where the 45-degree cross-polar channel is strong; ellipsometry (eq. (16))
   on the faces: straight runs of the contour (:func:`face_lines`), the face echo of each
   position and its bistatic specular point by the image method (:func:`face_echoes`), the
   incidence angle ``sin theta = |n x (T - R)| / r`` from the measured range
   (:func:`~fusion_center.objects.material.bistatic_incidence_angle`), specular points at
   least ``min_corner_distance`` from the face's imaged ends (Fig. 37: corner diffraction
   biases ``rho``).
Pure numpy.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from fusion_center.objects.fuzzy import FuzzyRpmImager
from fusion_center.objects.material import (
    bistatic_incidence_angle,
    depolarization_ratio,
    ellipsometry_permittivity,
    emissivity,
)
from fusion_center.objects.pulses import DynamicCorrelationSeparator
from node_agent.dsp.deconvolution import WienerDeconvolver

C = 299792458.0
FloatArray = npt.NDArray[np.float64]


@dataclass(frozen=True, slots=True, kw_only=True)
class ScanData:
    """One circular scan.

    Attributes
    ----------
    h : dict
        Channel name (``vv``, ``hh``, ``hv``, ``vh``, ``pp``, ``pm``) -> impulse responses,
        float, shape (P, n).
    poses : ndarray, float64, shape (P, 4)
        Sensor pose ``[x, y, z, yaw]`` at each position, in track order.
    tx, rx : ndarray, float64, shape (P, 2)
        World x, y of the transmitting and receiving antenna at each position.
    fs, t0 : float
        Sampling: sample k at ``t0 + k / fs`` after emission.
    """

    h: dict[str, FloatArray]
    poses: FloatArray
    tx: FloatArray
    rx: FloatArray
    fs: float
    t0: float


@dataclass(frozen=True, slots=True, kw_only=True)
class ScanResult:
    """Output of :func:`process_scan`.

    Attributes
    ----------
    ranges : ndarray, float64, shape (P, M)
        Bistatic wavefront ranges per position, ascending, NaN-padded, m.
    points : ndarray, float64, shape (P, M, 2)
        Fuzzy image point of each wavefront, world x, y, m.
    contour : ndarray, float64, shape (Q, 2)
        The 2-D contour (first wavefront of each position, track order).
    closed : bool
        The track was a full circle.
    depolarization : float
        Median ``P_VH / P_VV`` around the first wavefront.
    corner_points : ndarray, float64, shape (K, 2)
        Contour points where the 45-degree cross-polar channel is strong (corners).
    permittivity, emissivity : float
        Eq. (16) estimate over the face positions (NaN: no usable face).
    metal_like : bool
        ``|1 + rho|`` below 1 %: both polarizations reflect alike (a conductor).
    n_face_positions : int
        Positions used by the ellipsometry.
    """

    ranges: FloatArray
    points: FloatArray
    contour: FloatArray
    closed: bool
    depolarization: float
    corner_points: FloatArray
    permittivity: float
    emissivity: float
    metal_like: bool
    n_face_positions: int


def sample_at(h: npt.ArrayLike, delay: npt.ArrayLike) -> FloatArray:
    """Band-limited (Fourier) interpolation of each row of ``h`` (P, n) at a fractional
    sample ``delay`` (P,): the amplitude of an echo between two samples."""
    x = np.asarray(h, float)
    n = x.shape[-1]
    spec = np.fft.rfft(x, axis=-1)
    k = np.arange(spec.shape[-1])
    w = np.where(k == 0, 1.0, 2.0)
    if n % 2 == 0:
        w[-1] = 1.0
    phase = np.exp(2j * np.pi * k * np.asarray(delay, float)[:, None] / n)
    return np.real(np.sum(w * spec * phase, axis=-1)) / n


def track_centre(poses: npt.ArrayLike) -> FloatArray:
    """The point all boresights aim at: least-squares intersection of the lines through each
    pose ``[x, y, z, yaw]`` along its yaw (the circle's centre, also for a partial circle)."""
    p = np.asarray(poses, float)
    d = np.column_stack([np.cos(p[:, 3]), np.sin(p[:, 3])])
    proj = np.eye(2) - d[:, :, None] * d[:, None, :]  # (P, 2, 2): normal to each line
    return np.linalg.solve(proj.sum(axis=0), np.einsum("pij,pj->i", proj, p[:, :2]))


def track_is_closed(yaw: npt.ArrayLike) -> bool:
    """Whether the headings cover a full turn (sum of wrapped steps >= 359 degrees)."""
    d = np.diff(np.unwrap(np.asarray(yaw, float)))
    return bool(abs(d.sum()) + np.median(np.abs(d)) >= np.deg2rad(359.0))


@dataclass(frozen=True, slots=True, kw_only=True)
class FaceLine:
    """A straight face of the imaged contour: the line ``n . x = c`` and its imaged extent.

    Attributes
    ----------
    normal : ndarray, float64, shape (2,)
        Unit normal (sign arbitrary).
    offset : float
        ``c`` in ``n . x = c``, m.
    t_min, t_max : float
        Extent along the tangent ``(-n_y, n_x)``, m: the contour points on the line,
        corner echoes (imaged at the corner, on the line) included.
    """

    normal: FloatArray
    offset: float
    t_min: float
    t_max: float


@dataclass(frozen=True, slots=True, kw_only=True)
class FaceEchoes:
    """Specular face echo of each position (:func:`face_echoes`); arrays of shape (P,).

    Attributes
    ----------
    found : ndarray, bool
        A wavefront matches a face's predicted specular range.
    range : ndarray, float64
        The matched wavefront's bistatic range, m (NaN: none).
    theta : ndarray, float64
        Incidence angle from the measured range and the face normal, rad.
    point : ndarray, float64, shape (P, 2)
        Bistatic specular point on the face (image method), world x, y, m.
    corner_distance : ndarray, float64
        Distance of the specular point from the nearer end of the face, m.
    """

    found: npt.NDArray[np.bool_]
    range: FloatArray
    theta: FloatArray
    point: FloatArray
    corner_distance: FloatArray


def face_lines(
    points: npt.ArrayLike,
    contour: npt.ArrayLike,
    *,
    radius: float = 0.06,
    on_line: float = 0.01,
    max_turn: float = np.deg2rad(5.0),
    max_gap: float = 0.3,
    min_points: int = 5,
) -> list[FaceLine]:
    """Straight faces of an imaged contour.

    A point is on a face when the contour within ``radius`` is a line (PCA: the smaller
    eigenvalue below 2 % of the larger). Runs of such points in track order with normals
    within ``max_turn`` and offsets within ``on_line`` form one face, collinear runs merge
    (a face with an unimaged stretch), the line is the total-least-squares fit of its points,
    and its extent is the contiguous stretch (gaps below ``max_gap``) of contour points
    within ``on_line`` of it.

    Parameters
    ----------
    points : array_like, shape (P, 2)
        First-wavefront image point of each position in track order (NaN: none), m.
    contour : array_like, shape (Q, 2)
        All contour points, m.
    """
    pts = np.asarray(points, float)
    allc = np.asarray(contour, float)
    q = pts[np.isfinite(pts[:, 0])]
    if len(q) < min_points:
        return []
    d2 = np.sum((q[:, None, :] - q[None, :, :]) ** 2, axis=-1)
    near = d2 < radius**2
    cnt = near.sum(axis=1)
    mean = (near[..., None] * q[None]).sum(axis=1) / cnt[:, None]
    dev = np.where(near[..., None], q[None] - mean[:, None, :], 0.0)
    cov = np.einsum("pqi,pqj->pij", dev, dev) / cnt[:, None, None]
    w, v = np.linalg.eigh(cov)
    straight = (cnt >= min_points) & (w[:, 0] < 0.02 * w[:, 1]) & (w[:, 1] > 1e-4)
    qs, ns = q[straight], v[straight, :, 0]
    if len(qs) < min_points:
        return []
    # Runs: consecutive straight points with a similar normal on each other's line.
    same = (np.abs(np.sum(ns[1:] * ns[:-1], axis=1)) > np.cos(max_turn)) & (
        np.abs(np.sum((qs[1:] - qs[:-1]) * ns[:-1], axis=1)) < on_line
    )
    label = np.concatenate([[0], np.cumsum(~same)])
    runs = [np.flatnonzero(label == k) for k in range(label[-1] + 1)]
    runs = [r for r in runs if len(r) >= min_points]
    merged: list[np.ndarray] = []
    for r in runs:  # a few runs per scan
        n_r = _line_normal(qs[r])
        for k, m in enumerate(merged):
            n_m = _line_normal(qs[m])
            off = np.abs(np.sum((qs[r] - qs[m].mean(axis=0)) * n_m, axis=1))
            if abs(n_r @ n_m) > np.cos(max_turn) and np.median(off) < on_line:
                merged[k] = np.concatenate([m, r])
                break
        else:
            merged.append(r)
    faces = []
    for m in merged:
        n = _line_normal(qs[m])
        centre = qs[m].mean(axis=0)
        tangent = np.array([-n[1], n[0]])
        member = np.abs((allc - centre) @ n) < on_line
        t = np.sort((allc[member] - centre) @ tangent)
        t0 = float(np.median((qs[m] - centre) @ tangent))
        gaps = np.flatnonzero(np.diff(t) > max_gap)
        lo_gap = gaps[t[gaps] < t0]
        hi_gap = gaps[t[gaps + 1] > t0]
        t_min = t[lo_gap[-1] + 1] if len(lo_gap) else t[0]
        t_max = t[hi_gap[0]] if len(hi_gap) else t[-1]
        # t is measured from ``centre``; FaceLine's from the origin's foot on the line.
        shift = float(centre @ tangent)
        faces.append(
            FaceLine(
                normal=n,
                offset=float(centre @ n),
                t_min=float(t_min) + shift,
                t_max=float(t_max) + shift,
            )
        )
    return faces


def _line_normal(q: FloatArray) -> FloatArray:
    """Unit normal of the total-least-squares line through points ``q`` (K, 2)."""
    dev = q - q.mean(axis=0)
    _, vecs = np.linalg.eigh(dev.T @ dev)
    return vecs[:, 0]


def face_echoes(
    tx: npt.ArrayLike,
    rx: npt.ArrayLike,
    ranges: npt.ArrayLike,
    faces: list[FaceLine],
    *,
    tolerance: float = 0.01,
) -> FaceEchoes:
    """The specular echo of each imaged face at each position, with the bistatic geometry.

    For a face (line ``n . x = c``) the transmitter's mirror image is
    ``T' = T - 2 (n . T - c) n``; the specular path has the length ``|R - T'|`` and meets the
    face where the segment ``T' R`` crosses it (image method). The wavefront within
    ``tolerance`` of that predicted range is the face's echo; its *measured* range gives
    the incidence angle ``sin theta = |n x (T - R)| / r``
    (:func:`fusion_center.objects.material.bistatic_incidence_angle`). Where several faces
    match, the nearest (shortest range) is kept. Only faces in front of both antennas, with
    the specular point inside the face's imaged extent, count.

    Parameters
    ----------
    tx, rx : array_like, shape (P, 2)
        World x, y of the transmitter and receiver, m.
    ranges : array_like, shape (P, M)
        Bistatic wavefront ranges, m (NaN: none).
    faces : list of FaceLine
    """
    tx, rx = np.asarray(tx, float), np.asarray(rx, float)
    r = np.asarray(ranges, float)
    n_pos = len(tx)
    best_r = np.full(n_pos, np.nan)
    best_point = np.full((n_pos, 2), np.nan)
    best_theta = np.full(n_pos, np.nan)
    best_corner = np.full(n_pos, np.nan)
    for f in faces:  # a few faces per scan; vectorised over positions
        n = f.normal
        nn = n * np.sign(np.median(tx @ n - f.offset))  # toward the antennas
        c = f.offset * float(nn @ n)
        ht, hr = tx @ nn - c, rx @ nn - c  # heights of T and R above the face
        r_pred = np.linalg.norm(rx - (tx - 2 * ht[:, None] * nn), axis=1)
        # The specular point splits the feet of T and R on the face in the ratio ht : hr.
        foot_t, foot_r = tx - ht[:, None] * nn, rx - hr[:, None] * nn
        with np.errstate(invalid="ignore", divide="ignore"):
            point = foot_t + (ht / (ht + hr))[:, None] * (foot_r - foot_t)
        tangent = np.array([-n[1], n[0]])
        t = point @ tangent
        corner = np.minimum(t - f.t_min, f.t_max - t)
        err = np.abs(r - r_pred[:, None])
        err = np.where(np.isfinite(err), err, np.inf)
        k = np.argmin(err, axis=1)
        r_face = r[np.arange(n_pos), k]
        ok = (err[np.arange(n_pos), k] < tolerance) & (ht > 0) & (hr > 0) & (corner >= 0)
        better = ok & ~(r_face >= best_r)  # NaN best: take it
        best_r = np.where(better, r_face, best_r)
        best_point = np.where(better[:, None], point, best_point)
        best_corner = np.where(better, corner, best_corner)
        best_theta = np.where(
            better,
            bistatic_incidence_angle(tx, rx, r_face, np.broadcast_to(n, tx.shape)),
            best_theta,
        )
    return FaceEchoes(
        found=np.isfinite(best_r),
        range=best_r,
        theta=best_theta,
        point=best_point,
        corner_distance=best_corner,
    )


def process_scan(
    scan: ScanData,
    *,
    max_fronts: int = 6,
    dynamic_range_db: float = 30.0,
    pulse_half_width: int = 12,
    min_corner_distance: float = 0.25,
) -> ScanResult:
    """Wavefronts, fuzzy contour, polarimetry and ellipsometry of one scan (see module doc)."""
    vv, hh = scan.h["vv"].astype(float), scan.h["hh"].astype(float)
    n_pos, n = vv.shape
    baseline = float(np.median(np.linalg.norm(scan.tx - scan.rx, axis=1)))
    centre = track_centre(scan.poses)
    radius = float(np.median(np.linalg.norm(scan.poses[:, :2] - centre, axis=1)))
    # Range gate (bistatic path): from the antennas to 0.3 m beyond the track centre.
    ranges_axis = C * (scan.t0 + np.arange(n) / scan.fs)
    gate = (ranges_axis > 0.1) & (ranges_axis < 2 * radius + baseline + 0.6)
    if gate.sum() < 2 * pulse_half_width + 1:
        raise ValueError(
            f"range gate of {gate.sum()} samples: track radius {radius:.3g} m too small"
        )
    co = vv + hh  # a face returns V and H with the same sign (S = Gamma I at normal incidence)
    env = np.abs(np.where(gate, co, 0.0))
    k_pos, k_max = np.unravel_index(int(np.argmax(env)), env.shape)
    # The reference's time origin is the echo's peak between samples (band-limited
    # interpolation on a 1/64-sample grid), not the nearest sample: else every range of the
    # scan is off by up to half a sample (2 cm), and so is the incidence angle from it.
    fine = k_max + np.arange(-32, 33) / 64
    peak_val = sample_at(np.broadcast_to(co[k_pos], (len(fine), n)), fine)
    origin = float(fine[np.argmax(np.abs(peak_val))]) - k_max
    lo = max(k_max - pulse_half_width, 0)
    ref = co[k_pos, lo : k_max + pulse_half_width + 1]
    centre_idx = k_max - lo
    wiener = WienerDeconvolver(ref, n, snr_db=30.0, centre=centre_idx)
    deconv = wiener.apply(co)
    ref_out = wiener.apply(np.roll(np.pad(ref, (0, n - len(ref))), -centre_idx))
    ref_out = np.roll(ref_out, pulse_half_width)[: 2 * pulse_half_width + 1]
    noise_out = float(np.median(np.abs(deconv[:, ~gate])) / 0.6745) if (~gate).any() else 1e-6
    # Pulse separation on the gated window only (a short FFT per position).
    g_idx = np.flatnonzero(gate)
    g0, g1 = int(g_idx[0]), int(g_idx[-1]) + 1
    win = g1 - g0
    dcm = DynamicCorrelationSeparator(
        ref_out, win, centre=pulse_half_width, max_pulses=max_fronts, threshold=6.0
    )
    ranges = np.full((n_pos, max_fronts), np.nan)
    amps = np.full((n_pos, max_fronts), np.nan)
    for i in range(n_pos):  # one DCM run per scan position, not per sample
        p = dcm.separate(deconv[i, g0:g1], noise_out)
        m = min(len(p.delays), max_fronts)
        ranges[i, :m] = C * (scan.t0 + (g0 + origin + p.delays[:m]) / scan.fs)
        amps[i, :m] = p.amplitudes[:m]
    strong = np.abs(amps) >= np.nanmax(np.abs(amps)) * 10 ** (-dynamic_range_db / 20)
    ranges = np.where(strong, ranges, np.nan)
    order = np.argsort(np.where(np.isfinite(ranges), ranges, np.inf), axis=1)
    ranges = np.take_along_axis(ranges, order, axis=1)
    closed = track_is_closed(scan.poses[:, 3])
    toward = np.column_stack([np.cos(scan.poses[:, 3]), np.sin(scan.poses[:, 3])])
    img = FuzzyRpmImager().image(
        scan.poses[:, :2], ranges, toward, closed=closed, antennas=(scan.tx, scan.rx)
    )
    # Polarimetry around the first wavefront of each position (+-3 samples).
    first = ranges[:, 0]
    has = np.isfinite(first)
    k_first = np.where(has, np.round((first / C - scan.t0) * scan.fs), 0).astype(int)
    win_idx = np.clip(k_first[:, None] + np.arange(-3, 4), 0, n - 1)

    def take(ch: str) -> FloatArray:
        return np.take_along_axis(scan.h[ch].astype(float), win_idx, axis=1)

    depol = depolarization_ratio(take("vv"), take("vh"))[has]
    # Corners: wavefronts (any, not only the first: a dihedral lies behind the faces) whose
    # 45-degree cross-polar echo is strong against the co-polar one. A plate gives none, a
    # dihedral only cross-polar, a wedge about a third of its co-polar amplitude.
    fronts = np.isfinite(ranges)
    k_all = np.where(fronts, np.round((ranges / C - scan.t0) * scan.fs), 0).astype(int)
    w_all = np.clip(k_all[..., None] + np.arange(-2, 3), 0, n - 1).reshape(n_pos, -1)

    def peak(ch: str) -> FloatArray:
        v = np.take_along_axis(scan.h[ch].astype(float), w_all, axis=1)
        return np.abs(v).reshape(n_pos, -1, 5).max(axis=-1)

    co45, cross45 = peak("pp"), peak("pm")
    # Quasi-monostatic only: at oblique bistatic incidence a plate's cross-polar share
    # ((Gamma_TE + Gamma_TM) / 2) grows too. Weak echoes (DCM residue) are left out.
    significant = cross45 > 0.1 * np.max(np.where(fronts, cross45, 0.0), initial=0.0)
    corner_mask = fronts & significant & (cross45 > 0.25 * co45) & np.isfinite(img.points[..., 0])
    # Ellipsometry on faces (straight runs of the contour), away from their ends.
    faces = face_lines(img.points[:, 0, :], img.contour)
    corners = img.points[corner_mask]
    eps_est, face_n, metal = np.nan, 0, False
    if faces:
        fit = face_echoes(scan.tx, scan.rx, ranges, faces)
        d_face = np.where(fit.found, (fit.range / C - scan.t0) * scan.fs, 0.0)
        a_vv, a_hh = sample_at(vv, d_face), sample_at(hh, d_face)
        with np.errstate(invalid="ignore", divide="ignore"):
            rho = -a_hh / a_vv
        eps = ellipsometry_permittivity(rho, fit.theta)
        # Eq. (16) is ill-conditioned near normal incidence (rho -> -1): above 10 deg only.
        # Corner diffraction biases rho (Fig. 37): specular points >= 25 cm from the face's
        # imaged ends, where the benchmark's correction table is flat.
        sel = (
            fit.found
            & np.isfinite(eps)
            & (fit.theta > np.deg2rad(10.0))
            & (fit.corner_distance > min_corner_distance)
        )
        face_n = int(sel.sum())
        if face_n:
            eps_est = float(np.median(eps[sel]))
            metal = bool(np.median(np.abs(1 + rho[sel])) < 0.01)
    return ScanResult(
        ranges=ranges,
        points=img.points,
        contour=img.contour,
        closed=closed,
        depolarization=float(np.median(depol)) if depol.size else float("nan"),
        corner_points=corners,
        permittivity=eps_est,
        emissivity=float(emissivity(eps_est)) if np.isfinite(eps_est) else float("nan"),
        metal_like=metal,
        n_face_positions=face_n,
    )
