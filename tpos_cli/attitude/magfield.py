"""The magnetic field a log saw: the Earth field, disturbances that move with the sensor, and room disturbances.

A magnetometer measures m_b = C^T m_n + b + noise, with m_n the local field (NED) and b an offset fixed in
the body (hard iron: a magnet or a phone attached to the device). Over a short window the gyro alone gives
the relative rotation R_k (from the window's first sample) to a fraction of a degree, so two models can be
fitted to the window's samples by linear least squares:

- room-fixed: m_b,k = R_k^T m0 (3 unknowns: the field in the window's first body frame);
- body-fixed offset: m_b,k = R_k^T m0 + b (6 unknowns), separable only when the window turns.

A disturbance that moves with the sensor is a constant b: the offset model then removes most of the
residual (its variance at least halves) and b is well determined. A disturbance that stays in the room
(a magnet on the table, steel in a wall) is neither: the device moves through it, and its field changes
with position, not with orientation, so the offset explains little. That is the test of `survey`;
`apply` removes the body offsets (carrying one to a neighbouring window that does not turn when it
brings that window's field magnitude closer to the Earth field), takes the Earth field's magnitude and
dip as medians over the windows (robust to the disturbed minority), and marks as disturbed the samples
whose field magnitude (0.5 s mean) stays off that reference by more than three robust SDs of the
window magnitudes: those are left to the gyro. The Earth field the filters use (`FieldSurvey.norm_ut`,
`dip_rad`) is the median over the windows that one of the two models explains (the adopted fit's residual
within `fit_tol` times the log's median one): a window whose field changes inside it (a magnet being
attached or removed, a room disturbance passed through) has no magnitude of its own, and in a log whose
windows form two populations (still windows that keep an offset, turning windows with it removed) a few such
windows move the plain median across the gap (BROAD 26 with a planted magnet: 44.68 -> 45.16 uT, and LF1's
backward run then refused the field for most of the log). The offset carrying and the magnitude test keep
the median over every window (their figures on the real logs are unchanged).

The filters compare each sample with one fixed Earth vector; how far the log's field departs from it
(`FieldSurvey.field_sd_ut`, `field_sd_ut`) is, beside the sensor's white noise, the rest of the update's error.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tpos_cli.frames.rotation import rotvec_to_dcm

#: samples of neighbouring rows are correlated (resampled, filtered magnetometers): the LSQ covariance
#: of a window fit is scaled by the number of rows per 0.1 s so that b's SD is not over-confident
_CORR_S = 0.1


@dataclass(frozen=True)
class FieldWindow:
    """One survey window: rows [i0, i1), residual RMS (uT) of the room-fixed and body-offset fits, the
    fitted offset b (uT, body), its SD, whether the offset model was adopted, and the Earth field's
    magnitude (uT) and dip (rad, positive down) of the adopted model."""

    i0: int
    i1: int
    rms_room_ut: float
    rms_body_ut: float
    offset_ut: np.ndarray
    offset_sd_ut: float
    body_fixed: bool
    norm_ut: float
    dip_rad: float


@dataclass(frozen=True)
class FieldSurvey:
    """The magnetometer with the body-fixed offsets removed (N,3) uT, NaN where disturbed; the Earth
    field magnitude (uT) and dip (rad); the tolerance of the magnitude test (uT); the windows."""

    mag_b_ut: np.ndarray
    norm_ut: float
    dip_rad: float
    norm_tol_ut: float
    disturbed: np.ndarray
    windows: tuple[FieldWindow, ...]
    #: per-axis SD (uT) of the field's departure from the one Earth vector (`field_sd_ut`), 0 without the white noise
    field_sd_ut: float = 0.0

    def summary(self) -> dict:
        body = [w for w in self.windows if w.body_fixed]
        return {"earth_field_ut": round(self.norm_ut, 3), "dip_deg": round(float(np.degrees(self.dip_rad)), 3),
                "norm_tol_ut": round(self.norm_tol_ut, 3), "field_sd_ut": round(self.field_sd_ut, 3),
                "windows": len(self.windows),
                "body_fixed_windows": len(body), "disturbed_fraction": round(float(self.disturbed.mean()), 4),
                "offsets_ut": [[round(float(x), 2) for x in w.offset_ut] for w in body[:20]]}

    def unresolved_offset_ut(self, share: float = 0.25) -> float:
        """Magnitude (uT) of a body-fixed offset that the windows the survey could not separate (those that
        do not turn, the alignments' still windows among them) may still hold; 0 when the survey shows none.
        Where the survey removed an offset b, the field left has the Earth field's magnitude; when that
        magnitude (median over those windows) differs from the reference by more than the magnitude test's
        tolerance and by more than `share` of |b| (median), the reference itself, taken mostly from windows
        that kept their offset, holds one: a magnet present in the still windows too. The figure is then
        the median |b|. One adopted window suffices: it passed the fit's own tests (`fit_window`: the offset
        halves the residual variance and is known to better than 1 uT), which a room disturbance does not."""
        body = [w for w in self.windows if w.body_fixed]
        if not body:
            return 0.0
        gap = abs(float(np.median([w.norm_ut for w in body])) - self.norm_ut)
        b = self.offset_ut()
        return b if gap > max(self.norm_tol_ut, share * b) else 0.0

    def offset_ut(self) -> float:
        """Median magnitude (uT) of the body-fixed offsets the survey fitted; 0 without any."""
        body = [np.linalg.norm(w.offset_ut) for w in self.windows if w.body_fixed]
        return float(np.median(body)) if body else 0.0


def _relative_rotations(t_s, gyro_b_rps, bias_rps, i0, i1):
    """(i1 - i0, 3, 3) attitude of rows [i0, i1) relative to row i0, carried by the bias-corrected gyro."""
    R = np.empty((i1 - i0, 3, 3))
    # every step's rotation in one call (row by row the same numbers as one call per step, ~30x faster)
    steps = rotvec_to_dcm((np.asarray(gyro_b_rps[i0 + 1:i1]) - bias_rps) * np.diff(np.asarray(t_s[i0:i1]))[:, None])
    C = np.eye(3)
    for j in range(i1 - i0):
        if j > 0:
            C = C @ steps[j - 1]
        R[j] = C
    return R


def fit_window(t_s, gyro_b_rps, acc_b_mps2, mag_b_ut, bias_rps, i0, i1, *, var_ratio=0.5, max_offset_sd_ut=1.0) -> FieldWindow:
    """Room-fixed and body-offset fits of rows [i0, i1) (module docstring). The offset model is adopted
    when it leaves at most `var_ratio` of the room-fixed residual variance and its offset SD is below
    `max_offset_sd_ut` (the window turned enough to separate it)."""
    R = _relative_rotations(t_s, gyro_b_rps, bias_rps, i0, i1)
    Rt = np.swapaxes(R, 1, 2)
    m = np.asarray(mag_b_ut[i0:i1], dtype=float)
    ok = np.all(np.isfinite(m), axis=1)
    y = m[ok].reshape(-1)
    A1 = Rt[ok].reshape(-1, 3)
    x1 = np.linalg.lstsq(A1, y, rcond=None)[0]
    r1 = float(np.sqrt(np.mean((y - A1 @ x1) ** 2)))
    A2 = np.concatenate([Rt[ok], np.broadcast_to(np.eye(3), (int(ok.sum()), 3, 3))], axis=2).reshape(-1, 6)
    x2 = np.linalg.lstsq(A2, y, rcond=None)[0]
    r2 = float(np.sqrt(np.mean((y - A2 @ x2) ** 2)))
    dt = float(np.median(np.diff(t_s[i0:i1])))
    rows_corr = max(1.0, _CORR_S / dt)
    cov = np.linalg.pinv(A2.T @ A2) * r2**2 * rows_corr
    sd_b = float(np.sqrt(np.max(np.diag(cov)[3:])))
    body = bool(r2**2 <= var_ratio * r1**2 and sd_b < max_offset_sd_ut)
    m0 = x2[:3] if body else x1
    up = np.einsum("nij,nj->ni", R[ok], np.asarray(acc_b_mps2[i0:i1], dtype=float)[ok]).mean(axis=0)
    up = up / np.linalg.norm(up)  # specific force at rest points up
    nrm = float(np.linalg.norm(m0))
    return FieldWindow(int(i0), int(i1), r1, r2, x2[3:] if body else np.zeros(3), sd_b, body, nrm,
                       float(np.arcsin(np.clip(-(m0 @ up) / nrm, -1.0, 1.0))))


def _reference(wins, prior, cluster_ut=3.0, cluster_dip_rad=0.05236, min_share=0.1):
    """(norm, dip, member windows) of the Earth field: the median over the windows. With a `prior` (norm uT, dip rad;
    the IGRF at the log's place and date), the median over the cluster of windows (field within
    `cluster_ut` and `cluster_dip_rad` (3 deg) of one another, at least `min_share` of the windows or
    within those tolerances of the prior) nearest the prior: a disturbance that covers most of the log
    must not become the reference."""
    nw = np.array([w.norm_ut for w in wins])
    dw = np.array([w.dip_rad for w in wins])
    every = np.ones(nw.size, dtype=bool)
    if prior is None or nw.size < 3:
        return float(np.median(nw)), float(np.median(dw)), every
    members = (np.abs(nw[:, None] - nw[None, :]) <= cluster_ut) & (np.abs(dw[:, None] - dw[None, :]) <= cluster_dip_rad)
    support = members.sum(axis=1)
    # a cluster qualifies by its size, or, however small (a clean stretch before a disturbance that
    # lasts to the end), by agreeing with the prior within the cluster tolerance
    near = (np.abs(nw - prior[0]) <= cluster_ut) & (np.abs(dw - prior[1]) <= cluster_dip_rad)
    cand = np.flatnonzero((support >= max(2, min_share * nw.size)) | near)
    if cand.size == 0:
        return float(np.median(nw)), float(np.median(dw)), every
    dist = np.hypot((nw[cand] - prior[0]) / cluster_ut, (dw[cand] - prior[1]) / cluster_dip_rad)
    m = members[cand[int(np.argmin(dist))]]
    return float(np.median(nw[m])), float(np.median(dw[m])), m


def field_sd_ut(norm_lp_ut, rows_lp: int, wins, members, norm_ut: float, dip_rad: float, white_ut: float,
                rows_corr: float) -> float:
    """Per-axis SD (uT) of the field's departure from the one Earth vector (`norm_ut`, `dip_rad`) the filters
    use, as white noise beside the sensor's `white_ut`: the update's R = (white^2 + sd^2) I, with 3 sd^2 the
    mean square departure the log shows, summed over the axes it shows it on. The departure is what is slow:
    it is read from means (`norm_lp_ut`, (N,), the field magnitude's mean over `rows_lp` rows around each
    sample, NaN where masked: the filters do not use those samples; the windows' fits), whose white noise
    (`white_ut^2` over the independent samples among their rows, `rows_corr` rows each) is subtracted; what
    is fast beyond the stated white noise is the noise figure's error, for the NIS check to name, not a field.

    - Along the field: mean((|m|_lp - norm)^2) over the samples. A magnitude needs no attitude, so the gyro's
      scale and misalignment errors, which a window fit's residual carries, do not enter.
    - Across the field in the vertical plane: each window's dip (the adopted fit's m0 against the gravity it
      saw) times the magnitude against the reference, mean square over the Earth field's `members` among
      `wins` (`_reference`: a disturbance enters neither) that hold no masked sample (a window a magnet
      passed through fits a field the filters do not see; all members if none is whole), plus the field's
      change inside a window, taken as large across as along (the mean over those windows of var(|m|_lp)).
    - Across the field horizontally the departure turns the field's azimuth: a filter takes it as heading, no
      innovation shows it and the log cannot measure it; it adds nothing.

    Mean squares, not robust SDs: R stands for the departure's mean square, and the departures are not
    Gaussian (a log's rest and motion windows form two populations, BROAD 02: -0.6 and +0.4 uT in magnitude,
    where 1.4826 MAD reads 1.5x their RMS); the robustness is in the masked samples and the members.
    0 without `white_ut`; each part is clipped at 0."""
    lp = np.asarray(norm_lp_ut, dtype=float)
    ref = [w for w, m in zip(wins, members) if m]
    if white_ut <= 0.0 or not ref or not np.isfinite(lp).any():
        return 0.0
    # a window's fit over samples the filters do not use (masked: a magnet passed) is not a field they see
    ref = [w for w in ref if np.isfinite(lp[w.i0:w.i1]).all()] or ref
    lp_var = white_ut**2 * min(1.0, rows_corr / max(rows_lp, 1))
    along = float(np.nanmean((lp - norm_ut) ** 2)) - lp_var
    inside = [float(np.nanvar(lp[w.i0:w.i1])) for w in ref if np.isfinite(lp[w.i0:w.i1]).sum() > 1]
    dd = norm_ut * (np.array([w.dip_rad for w in ref]) - dip_rad)
    mean_var = white_ut**2 * min(1.0, rows_corr / float(np.median([w.i1 - w.i0 for w in ref])))
    across = float(np.mean(dd**2)) - mean_var + (float(np.mean(inside)) - lp_var if inside else 0.0)
    return float(np.sqrt((max(along, 0.0) + max(across, 0.0)) / 3.0))


def survey(t_s, gyro_b_rps, acc_b_mps2, mag_b_ut, bias_rps, *, window_s=4.0, var_ratio=0.5,
           max_offset_sd_ut=1.0, lowpass_s=0.5, tol_sds=3.0, prior=None, fit_tol=3.0, white_ut=0.0) -> FieldSurvey:
    """Survey the whole log in windows of `window_s` (module docstring) and return the cleaned field;
    `prior` (norm uT, dip rad) of the Earth field picks the reference among clusters (`_reference`);
    `white_ut` the magnetometer's white noise per axis (uT), for `field_sd_ut`."""
    t = np.asarray(t_s, dtype=float)
    mag = np.asarray(mag_b_ut, dtype=float)
    n = t.size
    dt = float(np.median(np.diff(t)))
    L = max(10, int(round(window_s / dt)))
    starts = list(range(0, max(n - L, 0) + 1, L)) or [0]
    if starts[-1] + L < n:
        starts.append(n - L)
    wins = [fit_window(t, gyro_b_rps, acc_b_mps2, mag, bias_rps, i0, min(i0 + L, n), var_ratio=var_ratio,
                       max_offset_sd_ut=max_offset_sd_ut) for i0 in starts]
    # a window that neither model explains (its adopted fit's residual well above the log's typical one: a field
    # that changed inside it, e.g. a magnet being attached) has no field magnitude to vote with
    resid = np.array([w.rms_body_ut if w.body_fixed else w.rms_room_ut for w in wins])
    voters = np.flatnonzero(resid <= fit_tol * np.median(resid))
    if voters.size < 3:
        voters = np.arange(len(wins))
    earth_norm, earth_dip, earth_wins = _reference([wins[i] for i in voters], prior)
    norm_ref, dip_ref, ref_wins = _reference(wins, prior)
    out = mag.copy()
    fitted = [i for i, w in enumerate(wins) if w.body_fixed]
    done = np.zeros(n, dtype=bool)
    for i, w in enumerate(wins):
        sl = slice(w.i0, w.i1)
        b = w.offset_ut if w.body_fixed else None
        if b is None and fitted:
            # a window that does not turn keeps the nearest window's offset if that explains its magnitude better
            j = min(fitted, key=lambda j: abs(j - i))
            raw = abs(np.nanmean(np.linalg.norm(mag[sl], axis=1)) - norm_ref)
            cor = abs(np.nanmean(np.linalg.norm(mag[sl] - wins[j].offset_ut, axis=1)) - norm_ref)
            if cor < raw:
                b = wins[j].offset_ut
        keep = ~done[sl]  # overlapping last window: rows already corrected stay as they are
        if b is not None:
            out[sl][keep] = mag[sl][keep] - b
        done[sl] = True
    nw = np.array([np.nanmean(np.linalg.norm(out[w.i0:w.i1], axis=1)) for w in wins])
    k = max(3, int(round(lowpass_s / dt)))
    nrm = np.linalg.norm(out, axis=1)
    # the spread of the reference windows' magnitudes, at least the sensor noise of a `lowpass_s` mean
    dn = np.diff(nrm[np.isfinite(nrm)])
    sd_lp = 1.4826 * float(np.median(np.abs(dn - np.median(dn)))) / np.sqrt(2.0 * k) if dn.size else 0.0
    tol = tol_sds * max(1.4826 * float(np.median(np.abs(nw[ref_wins] - norm_ref))), sd_lp)
    c = np.concatenate([[0.0], np.cumsum(np.nan_to_num(nrm, nan=norm_ref))])
    i = np.arange(n)
    lo, hi = np.clip(i - k // 2, 0, n), np.clip(i - k // 2 + k, 0, n)
    lp = (c[hi] - c[lo]) / (hi - lo)
    disturbed = np.abs(lp - norm_ref) > tol
    out[disturbed] = np.nan
    sd = field_sd_ut(np.where(disturbed, np.nan, lp), k, [wins[i] for i in voters], earth_wins, earth_norm, earth_dip,
                     white_ut, max(1.0, _CORR_S / dt))
    return FieldSurvey(out, earth_norm, earth_dip, tol, disturbed, tuple(wins), sd)


def reference_field_ned(norm_ut: float, dip_rad: float, declination_rad: float) -> np.ndarray:
    """The Earth field (NED, uT) of magnitude `norm_ut`, dip `dip_rad` (positive down) and declination."""
    h = norm_ut * np.cos(dip_rad)
    return np.array([h * np.cos(declination_rad), h * np.sin(declination_rad), norm_ut * np.sin(dip_rad)])


def field_heading_offsets_rad(C_nb, mag_b_ut, declination_rad: float) -> np.ndarray:
    """(N,) rad: the heading the field samples imply minus the solution's heading, wrapped to (-pi, pi]:
    the azimuth of the measured field's horizontal NED part (C_nb m_b) less the declination (Eq. 8 with
    the solution's tilt). NaN where a sample is missing. A heading the field agrees with gives zero mean."""
    m_n = np.einsum("nij,nj->ni", np.asarray(C_nb, dtype=float), np.asarray(mag_b_ut, dtype=float))
    a = np.arctan2(m_n[:, 1], m_n[:, 0]) - declination_rad
    return (a + np.pi) % (2.0 * np.pi) - np.pi
