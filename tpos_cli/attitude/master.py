"""No-reset federated master filter (paper 000 Eq. 23-27) with per-sample inclusion weights.

Eq. 27: x_g = P_g (sum_i P_i^-1 x_i), P_g = (sum_i P_i^-1)^-1. For the full model the local
estimates are rotations, so Eq. 27 is applied in the tangent space of a reference rotation:
x_i = log(C_i C_ref^T) (NED error vectors), C_g = exp(x_g) C_ref. For the paper's 8-state model
Eq. 27 is applied to the 8 DCM elements as written. There is no feedback to the local filters
("no-reset"), so a failed local filter cannot contaminate the other one. `weights` (S, N) scale
each local information matrix: 1 = the paper's fusion, 0 = excluded by the fault detector.
"""

from __future__ import annotations

import numpy as np

from tpos_cli.attitude.local import AttitudeSolution, paper8_solution
from tpos_cli.frames.rotation import dcm_to_rotvec, rotvec_to_dcm


def fuse(name: str, sols: list[AttitudeSolution], weights=None) -> AttitudeSolution:
    """Fuse local solutions sample by sample (Eq. 27); weights (S, N) in [0, 1], default all 1.

    Where every weight of a sample is 0 the plain fusion (all 1) is used for that sample.
    """
    S = len(sols)
    n = sols[0].t_s.size
    w = np.ones((S, n)) if weights is None else np.asarray(weights, dtype=float).reshape(S, n).copy()
    none = w.sum(axis=0) <= 0
    w[:, none] = 1.0
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
    info = np.zeros((n, 3, 3))
    iv = np.zeros((n, 3))
    infos = []
    for s, wi in zip(sols, w):
        d = dcm_to_rotvec(s.C_nb @ np.swapaxes(C_ref, 1, 2))
        Pi = wi[:, None, None] * np.linalg.inv(s.P_att)
        infos.append(Pi)
        info += Pi
        iv += np.einsum("nij,nj->ni", Pi, d)
    Pg = np.linalg.inv(info)
    xg = np.einsum("nij,nj->ni", Pg, iv)
    C = rotvec_to_dcm(xg) @ C_ref
    S_g = Q_g = None
    if all(s.S_ba is not None for s in sols):
        # the fused error is sum_i W_i e_i with W_i = P_g w_i P_i^-1: its accelerometer-bias sensitivity
        # is sum_i W_i S_i, and the parts the filters' own bias priors explain combine as sum_i W_i Q_i W_i^T
        S_g, Q_g = np.zeros((n, 3, 3)), np.zeros((n, 3, 3))
        for s, Pi in zip(sols, infos):
            W = Pg @ Pi
            S_g += W @ s.S_ba
            Q_g += W @ s.Q_ba @ np.swapaxes(W, 1, 2)
    return AttitudeSolution(name=name, t_s=sols[0].t_s, C_nb=C, P_att=0.5 * (Pg + np.swapaxes(Pg, 1, 2)), S_ba=S_g,
                            Q_ba=Q_g)


def consistency_nis(a: AttitudeSolution, b: AttitudeSolution) -> np.ndarray:
    """(N,) chi-square(3) statistic of the attitude difference of two solutions with P_a + P_b."""
    d = dcm_to_rotvec(a.C_nb @ np.swapaxes(b.C_nb, 1, 2))
    S = a.P_att + b.P_att
    return np.einsum("ni,ni->n", d, np.linalg.solve(S, d[..., None])[..., 0])
