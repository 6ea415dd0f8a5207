"""No-reset federated master filter (paper 000 Eq. 23-27) with per-sample inclusion weights.

Eq. 27: x_g = P_g (sum_i P_i^-1 x_i), P_g = (sum_i P_i^-1)^-1. For the full model the local
estimates are rotations, so Eq. 27 is applied in the tangent space of a reference rotation:
x_i = log(C_i C_ref^T) (NED error vectors), C_g = exp(x_g) C_ref. For the paper's 8-state model
Eq. 27 is applied to the 8 DCM elements as written. There is no feedback to the local filters
("no-reset"), so a failed local filter cannot contaminate the other one. `weights` (S, N) scale
each local information matrix: 1 = the paper's fusion, 0 = excluded by the fault detector.

Solutions that carry their sensitivity to the start alignment's heading error (`AttitudeSolution.s_al`,
e_i = a_i + s_i h, h ~ N(0, var_al), a_i independent) are not independent: LF1's heading prior is that
alignment and LF2's wall normal is its heading turned by the beams. Eq. 27 would count h once per filter
(on paper 000's 6.2.2 session, where the field is disturbed after 4 s and LF1 holds the alignment's heading,
fkf leaned on LF2, whose wall normal adds the beams' noise to the same heading: worse than LF1 alone).
They are fused with that cross-covariance (best linear unbiased combination of correlated estimates,
Bar-Shalom and Campo): stacked covariance B_ij = delta_ij A_i / w_i + var_al s_i s_j^T with
A_i = P_i - var_al s_i s_i^T, P_g = (sum_ij (B^-1)_ij)^-1, x_g = sum_i W_i x_i, W_i = P_g sum_j (B^-1)_ji.
With s_i = 0 this is Eq. 27; what the filters share besides h (the gyro, the accelerometer LF2 levels
with) stays bounded by Eq. 23's beta.

Solutions that carry their sensitivity to the gyro's constant scale/misalignment (`AttitudeSolution.S_gm`,
e_i = a_i + S_i vec(dM), dM ~ N(0, var_gm I9) shared by every solution of one gyro) are fused with the
weights their other errors give (the estimate is the one without that term), and the fused covariance gains
that shared error exactly for those weights: var_gm S_g S_g^T, S_g = sum_i W_i S_i (the runs' drifts
through the same turns are one error, so it is not averaged down).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from tpos_cli.attitude.local import AttitudeSolution, paper8_solution
from tpos_cli.frames.rotation import dcm_to_rotvec, rotvec_to_dcm

#: samples the full model fuses at a time (`fuse`): its temporaries (the stacked (3S, 3S) covariances, their
#: inverses, the gains, the sensitivities' products) are ~1.4 kB a sample for two solutions, 0.5 GB for an hour
#: at 100 Hz; by blocks of this size they stay under 0.1 GB. Each sample is fused on its own, so the result
#: does not depend on the block.
FUSE_BLOCK = 65536

#: the per-sample fields of a full-model solution that `fuse` reads (sliced by block) and returns
_FUSED = ("C_nb", "P_att", "S_ba", "Q_ba", "s_al", "S_gm")


def fuse(name: str, sols: list[AttitudeSolution], weights=None, independent: bool = False) -> AttitudeSolution:
    """Fuse local solutions sample by sample (Eq. 27); weights (S, N) in [0, 1], default all 1.

    Where every weight of a sample is 0 the plain fusion (all 1) is used for that sample. The shared
    alignment heading enters with its cross-covariance (module docstring) unless `independent` (the
    paper's plain Eq. 27). The full model is fused by blocks of `FUSE_BLOCK` samples.
    """
    S = len(sols)
    n = sols[0].t_s.size
    w = np.ones((S, n)) if weights is None else np.asarray(weights, dtype=float).reshape(S, n).copy()
    none = w.sum(axis=0) <= 0
    w[:, none] = 1.0
    if all(s.x8 is not None for s in sols) or n <= FUSE_BLOCK:
        return _fuse(name, sols, w, independent)
    out: dict = {}
    for i0 in range(0, n, FUSE_BLOCK):
        sl = slice(i0, min(i0 + FUSE_BLOCK, n))
        part = _fuse(name, [_rows(s, sl) for s in sols], w[:, sl], independent)
        if not out:
            out = {f: None if getattr(part, f) is None else np.empty((n, *getattr(part, f).shape[1:])) for f in _FUSED}
            var_al, var_gm = part.var_al, part.var_gm
        for f, a in out.items():
            if a is not None:
                a[sl] = getattr(part, f)
    return AttitudeSolution(name=name, t_s=sols[0].t_s, **out, var_al=var_al, var_gm=var_gm)


def _rows(sol: AttitudeSolution, sl: slice) -> AttitudeSolution:
    """`sol`'s samples `sl` (views) of the fields `fuse` reads."""
    return replace(sol, t_s=sol.t_s[sl], **{f: None if getattr(sol, f) is None else getattr(sol, f)[sl] for f in _FUSED})


def _fuse(name: str, sols: list[AttitudeSolution], w: np.ndarray, independent: bool) -> AttitudeSolution:
    """`fuse` of all samples at once, `w` (S, N) the weights with no all-zero sample."""
    n = sols[0].t_s.size
    if all(s.x8 is not None for s in sols):
        info = np.zeros((n, 8, 8))
        iv = np.zeros((n, 8))
        for s, wi in zip(sols, w):
            Pi = np.linalg.inv(s.P8)
            info += wi[:, None, None] * Pi
            iv += wi[:, None] * np.einsum("nij,nj->ni", Pi, s.x8)
        Pg = np.linalg.inv(info)
        xg = np.einsum("nij,nj->ni", Pg, iv)
        return paper8_solution(name, sols[0].t_s, xg, Pg)
    C_ref = sols[0].C_nb
    # a solution without the sensitivity (e.g. a backward run from its own end) holds none of h
    sens = [s.s_al for s in sols if s.s_al is not None]
    shared = bool(sens) and not independent
    var = max(s.var_al for s in sols) if shared else 0.0
    P_own = [s.P_att - gyro_scale_cov(s) for s in sols]
    if shared:
        sv = [np.zeros((n, 3)) if s.s_al is None else s.s_al for s in sols]
        A = [P - var * (si[:, :, None] * si[:, None, :]) for P, si in zip(P_own, sv)]
        Pg, Ws = _gains(A, sv, var, w)
    else:
        Pg, Ws = _gains(P_own, None, 0.0, w)
    xg = np.zeros((n, 3))
    for s, W in zip(sols, Ws):
        xg += np.einsum("nij,nj->ni", W, dcm_to_rotvec(s.C_nb @ np.swapaxes(C_ref, 1, 2)))
    C = rotvec_to_dcm(xg) @ C_ref
    S_g = Q_g = s_g = None
    if all(s.S_ba is not None for s in sols):
        # the fused error is sum_i W_i e_i: its accelerometer-bias sensitivity is sum_i W_i S_i, and the
        # parts the filters' own bias priors explain combine as sum_i W_i Q_i W_i^T
        S_g = sum(W @ s.S_ba for s, W in zip(sols, Ws))
        Q_g = sum(W @ s.Q_ba @ np.swapaxes(W, 1, 2) for s, W in zip(sols, Ws))
    if shared:
        s_g = sum(np.einsum("nij,nj->ni", W, si) for si, W in zip(sv, Ws))
    G_g, var_gm = None, 0.0
    if all(s.S_gm is not None for s in sols):
        var_gm = max(s.var_gm for s in sols)
        G_g = sum(W @ s.S_gm for s, W in zip(sols, Ws))
        Pg = Pg + var_gm * (G_g @ np.swapaxes(G_g, 1, 2))
    return AttitudeSolution(name=name, t_s=sols[0].t_s, C_nb=C, P_att=0.5 * (Pg + np.swapaxes(Pg, 1, 2)), S_ba=S_g,
                            Q_ba=Q_g, s_al=s_g, var_al=var, S_gm=G_g, var_gm=var_gm)


def gyro_scale_cov(sol: AttitudeSolution) -> np.ndarray | float:
    """(N,3,3) rad^2 share of `sol.P_att` that the gyro's constant scale/misalignment explains,
    var_gm S_gm S_gm^T (`AttitudeSolution.S_gm`); 0.0 without that sensitivity."""
    if sol.S_gm is None:
        return 0.0
    return sol.var_gm * (sol.S_gm @ np.swapaxes(sol.S_gm, 1, 2))


def _gains(A, s, var, w):
    """(P_g (N,3,3), [W_i (N,3,3)]): best linear unbiased fusion of estimates with errors a_i + s_i h,
    a_i ~ N(0, A_i) (N,3,3) independent, h ~ N(0, var) shared (s None: independent errors); w (k, N)
    scales A_i^-1; a solution with w = 0 at a sample gets W_i = 0 there (module docstring)."""
    k, n = len(A), A[0].shape[0]
    Ws = [np.zeros((n, 3, 3)) for _ in range(k)]
    Pg = np.zeros((n, 3, 3))
    inc = w > 0.0
    for pattern in np.unique(inc.T, axis=0):
        rows = np.flatnonzero(np.all(inc.T == pattern, axis=1))
        idx = np.flatnonzero(pattern)
        m = idx.size
        B = np.zeros((rows.size, 3 * m, 3 * m))
        for a, i in enumerate(idx):
            B[:, 3 * a:3 * a + 3, 3 * a:3 * a + 3] += A[i][rows] / w[i, rows][:, None, None]
            if s is not None:
                for b, j in enumerate(idx):
                    B[:, 3 * a:3 * a + 3, 3 * b:3 * b + 3] += var * (s[i][rows][:, :, None] * s[j][rows][:, None, :])
        Bi = np.linalg.inv(0.5 * (B + np.swapaxes(B, 1, 2)))
        HtBi = Bi.reshape(rows.size, m, 3, 3 * m).sum(axis=1)  # H^T B^-1, H = [I; ...; I]: block-row sums
        Pr = np.linalg.inv(HtBi.reshape(rows.size, 3, m, 3).sum(axis=2))
        Pg[rows] = Pr
        for a, i in enumerate(idx):
            Ws[i][rows] = Pr @ HtBi[:, :, 3 * a:3 * a + 3]
    return Pg, Ws


def difference_cov(a: AttitudeSolution, b: AttitudeSolution, gyro_scale: bool = True) -> np.ndarray:
    """(N,3,3) covariance of the attitude difference of two solutions: P_a + P_b less what they share,
    the start alignment's heading error (`AttitudeSolution.s_al`): - var_al (s_a s_b^T + s_b s_a^T), and
    the gyro's scale/misalignment (`AttitudeSolution.S_gm`): - var_gm (S_a S_b^T + S_b S_a^T). `gyro_scale`
    False: without the gyro's scale/misalignment at all (P_a - var_gm S_a S_a^T + ...), the covariance of the
    errors the forward/backward test scales (`smoother.fb_scale`)."""
    if not gyro_scale:
        return difference_cov(replace(a, P_att=a.P_att - gyro_scale_cov(a), S_gm=None),
                              replace(b, P_att=b.P_att - gyro_scale_cov(b), S_gm=None))
    D = a.P_att + b.P_att
    if a.s_al is not None and b.s_al is not None:
        X = max(a.var_al, b.var_al) * (a.s_al[:, :, None] * b.s_al[:, None, :])
        D = D - X - np.swapaxes(X, 1, 2)
    if a.S_gm is not None and b.S_gm is not None:
        X = max(a.var_gm, b.var_gm) * (a.S_gm @ np.swapaxes(b.S_gm, 1, 2))
        D = D - X - np.swapaxes(X, 1, 2)
    return D


def consistency_nis(a: AttitudeSolution, b: AttitudeSolution, acc_bias_var: float = 0.0) -> np.ndarray:
    """(N,) chi-square(3) statistic of the attitude difference of two solutions (`difference_cov`). With
    `acc_bias_var` > 0 and both sensitivities, the accelerometer bias b_a ~ N(0, acc_bias_var I) they carry
    (`AttitudeSolution.S_ba`) counts as it acts on the difference: the priors' shares Q_a + Q_b out,
    acc_bias_var (S_a - S_b)(S_a - S_b)^T in (`local.honest_covariance` for the difference)."""
    d = dcm_to_rotvec(a.C_nb @ np.swapaxes(b.C_nb, 1, 2))
    S = difference_cov(a, b)
    if acc_bias_var > 0.0 and a.S_ba is not None and b.S_ba is not None and a.Q_ba is not None and b.Q_ba is not None:
        E = a.S_ba - b.S_ba
        S = S - a.Q_ba - b.Q_ba + acc_bias_var * (E @ np.swapaxes(E, 1, 2))
    return np.einsum("ni,ni->n", d, np.linalg.solve(S, d[..., None])[..., 0])
