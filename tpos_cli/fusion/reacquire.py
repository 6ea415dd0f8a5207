"""Re-acquisition after consecutive gate rejections (issue 11 item 6): filter or fixes wrong?

When a slot's measurements (`fusion.engine.Measurements.slot`: GPS positions, GPS velocities, one
anchor's ranges, ...) keep failing the chi-square gate, either the filter has drifted off (its
covariance is too small for its error) or the measurements are wrong (multipath, a jump, a slow
wander that the R matched to their fix-to-fix scatter leaves out). nu_j = z_j - h(nominal_j) at
t_j: a drifted filter leaves in them its own error, which over a few fixes is a low-degree
polynomial in time (a position error p + v t + a t^2 / 2; a velocity error v + a t) starting from
where the last accepted row left it, plus the fixes' white noise of covariance R_j.

The rule (`FilterConfig.reacquire`; the drive pipeline's final forward and backward runs; without
it the row after `max_reject` rejections goes in as it is, the rule before):
- drift (`drift_nis_from_anchor`): the divided difference of order d + 1 (d = 2 for positions, 1
  for velocities) over the slot's last accepted row (its post-fit residual, re-measured after the
  update: `anchor`) and its last d + 1 rejections, w = sum_j c_j nu_j, c_j = 1 / prod_{i != j}
  (t_j - t_i), is zero for any polynomial through the anchor, and has covariance W = sum_j c_j^2 R_j
  from the fixes' noise alone. NIS(w) within the gate: the rejections continue the filter's error
  from where it stood. Fixes that stepped away (a multipath plateau) agree with each other but not
  with the anchor; fixes that scatter agree with nothing.
- beyond the stated accuracy (`nis_at_stated`): the row fails the gate even against
  H P H^T + F R F, F the fixes' stated SD over the SD the filter uses
  (`FilterConfig.stated_sd_factor`: the receiver's SDs, or the pipeline's stated `gps_sigma_*`,
  over the matched ones). Fixes whose errors wander slowly within their stated accuracy pass the
  drift test just as a drift of the filter does (the difference removes any smooth curve, whoever
  owns it); the stated accuracy is what tells them apart.
- both: re-acquired. The row goes in at its stated accuracy, with the filter's position and
  velocity covariance grown by the least factor lambda under which it passes the gate
  (`inflate_to_fit`; the attitude block and the rest kept: growing them, or growing P until the
  NIS is its mean instead of the gate's, let the next fixes turn the heading of navego's filter by
  tens of degrees). How the growth meets the cross terms with the attitude and the biases is the
  reading of where the error came from, and the fix alone cannot tell:
  - DRIFT, the error came the way the model makes errors, through the attitude and the biases
    (navego's early drift is its heading's): P <- D P D, the cross terms grown by sqrt(lambda), so
    the fix turns the attitude by the regression the model expects;
  - JUMP, an error the model did not produce (an IMU knock, a slip of the fixes): P_nn grown, the
    cross terms kept; under DRIFT a knock's fix turns the tilt the knock never touched (0.56 mrad on
    the planted knock: a second drift of 0.45 m).
  The trial (`fusion._kernels`): from a checkpoint of the loop's whole state at the re-acquired
  row, the stretch up to the slot's TRIAL_ROWS-th next row is run under JUMP, then under DRIFT,
  each scored by its rows' log-likelihood, sum of -(min(NIS, gate) + log det S) / 2 (the model's
  own S, before any growth; a row beyond the gate is an outlier under either reading: one wild
  fix must not pick it); DRIFT, the model's own reading, stands unless JUMP scores more than
  JUMP_LOG_ODDS higher (strong evidence), and then the stretch is run once more under JUMP.
  Re-acquisitions within the stretch take the reading under trial. Cost: at most three runs of
  the stretch per re-acquisition (rare).
- after `max_reject` rejections, no drift: beyond the stated accuracy the row goes in down-weighted,
  its R grown until its NIS is the gate's (`deweight_to_fit`: a filter is never locked out of its
  aiding, and a wrong fix moves it no more than one at the gate's edge); within it, as it is (its
  pull is bounded by the stated accuracy).
The revision (GPS rows, before a run of rejections starts): a row that fails the gate right after
its slot's previous row was accepted says that one of the two is wrong, and the gate alone blames
the new one. But a fix that slipped under the gate (navego's forward run at 10.7 s: one 1 Hz fix
0.7 m off its 20 Hz neighbours, NIS 17 under a gate of 21) has already pulled the velocity and the
tilt by as much as the filter's gain on it (0.7 m/s, 1.6 deg there), beyond what its covariance
holds; the next good fixes then fail the gate (NIS 22-45, five in a row) and the filter runs off
(4 m/s) until `max_reject` lets one in. So the kernel (`fusion._kernels`) checkpoints the loop's
state before each accepted GPS row; when the slot's next row fails the gate, the stretch from the
checkpoint is run again without that previous row, and the two readings are scored as the trial's
are, each row's min(NIS, gate) + log det S summed over the stretch, the row each reading takes
out counted at the gate's edge (`revision_favoured`). The revised reading (the previous row
rejected, the new row judged by the gate again) stands when it scores better; else the stretch is
run once more as it went and the new row is rejected (one wild fix in a good stream keeps the
rule before: its NIS stays beyond the gate from either state). Cost: one or two runs of one fix
interval per such rejection.

Scalar rows (one anchor's range) are never taken for a drift: a steady bias of one range (a
blocked line of sight) continues itself just as well.

Kernels over float64 arrays, called from the compiled filter loop (`fusion._kernels`); the ring
of a slot's last rejections is (n_slots, WINDOW, ...) arrays indexed by the slot's count of
consecutive rejections.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from tpos_cli.filters.kalman import innovation_into, nis_into  # S = H P H^T + R; nu^T S^-1 nu (-1: S not PD)
from tpos_cli.fusion.layout import ATT
from tpos_cli.fusion.measurements import Kind

WINDOW = 4  # rejections remembered per slot: d + 2 for the largest degree d = 2
N_INFLATED = ATT  # position and velocity errors: grown; attitude and the rest kept (`inflate_to_fit`: their cross terms)
_MAX_SQRT_LAMBDA = 1.0e4  # sqrt(lambda) at most: SDs grown 10^4-fold
JUMP, DRIFT = 0, 1  # the two readings of a re-acquired error (`inflate_to_fit`), tried in this order
TRIAL_ROWS = 10  # the stretch that scores them: up to the re-acquired slot's 10th next row (10 s of 1 Hz fixes)
JUMP_LOG_ODDS = 3.0  # JUMP only when the stretch favours it by more (strong evidence: 2 ln B > 6, Kass & Raftery
# 1995; chosen after seeing the margins: planted knock 6.3, start-off 33.5, navego 1.3 and 0.6, the walk 2.4)


@njit(cache=True)
def revision_favoured(cost_revised: float, cost_kept: float) -> bool:
    """The revision's choice: the stretch without the slot's previous row scores better (its cost,
    -2 log-likelihood up to terms alike for both, sum of min(NIS, gate) + log det S, the row each
    reading takes out at the gate's edge, is the smaller): the likelier reading of which row was wrong."""
    return cost_revised < cost_kept


@njit(cache=True)
def ring(n_slots):
    """Empty rings of rejected innovations: times (S, W), innovations (S, W, 3), R (S, W, 3, 3)."""
    return np.zeros((n_slots, WINDOW)), np.zeros((n_slots, WINDOW, 3)), np.zeros((n_slots, WINDOW, 3, 3))


@njit(cache=True)
def drift_degree(is_velocity: bool) -> int:
    """Degree of the polynomial drift taken out: 1 for velocities, 2 for positions and ranges."""
    return 1 if is_velocity else 2


@njit(cache=True)
def _put(ts, nus, Rs, i, t, nu, R, m):
    """ts[i] = t, nus[i, :m] = nu, Rs[i, :m, :m] = R: one row of a slot's ring or of the anchors."""
    ts[i] = t
    for a in range(m):
        nus[i, a] = nu[a]
        for b in range(m):
            Rs[i, a, b] = R[a, b]


@njit(cache=True)
def remember(ring_t, ring_nu, ring_R, slot, count, t, nu, R, m):
    """Store the slot's rejection number `count` (0-based within its run of consecutive
    rejections): time t (s), innovation nu (m,), R (m, m)."""
    _put(ring_t[slot], ring_nu[slot], ring_R[slot], count % WINDOW, t, nu, R, m)


@njit(cache=True)
def _divided_difference_nis(ts, nus, Rs, m):
    """NIS of w = sum_j c_j nus[j], c_j = 1 / prod_{i != j} (ts[j] - ts[i]) (the divided difference
    of order len(ts) - 1, zero for any polynomial of lower degree), against W = sum_j c_j^2 Rs[j];
    -1 when two times coincide or W is singular."""
    n = ts.shape[0]
    w = np.zeros(m)
    W = np.zeros((m, m))
    for jj in range(n):
        prod = 1.0
        for ii in range(n):
            if ii != jj:
                dt = ts[jj] - ts[ii]
                if dt == 0.0:
                    return -1.0
                prod *= dt
        c = 1.0 / prod
        for a in range(m):
            w[a] += c * nus[jj, a]
            for b in range(m):
                W[a, b] += c * c * Rs[jj, a, b]
    return nis_into(w, W, np.empty((m, m)), np.empty(m))


@njit(cache=True)
def drift_nis(ring_t, ring_nu, ring_R, slot, count, degree, m):
    """NIS of the divided difference of order degree + 1 over the slot's last degree + 2
    rejections (the last one number `count`); -1 when there are fewer, two share a time, its
    covariance is singular, or the rows are scalars (m = 1: one anchor's range cannot tell a
    drift of the filter from a steady bias of its own, e.g. a blocked line of sight)."""
    n = degree + 2
    if count + 1 < n or m < 2:
        return -1.0
    j = np.array([(count - jj) % WINDOW for jj in range(n)])
    return _divided_difference_nis(ring_t[slot, j], ring_nu[slot, j, :m], ring_R[slot, j, :m, :m], m)


@njit(cache=True)
def anchors(n_slots):
    """Each slot's last accepted row after its update: time (S,), post-fit residual (S, 3), R (S, 3, 3),
    set (S,) bool."""
    return np.zeros(n_slots), np.zeros((n_slots, 3)), np.zeros((n_slots, 3, 3)), np.zeros(n_slots, np.bool_)


@njit(cache=True)
def anchor(anc_t, anc_nu, anc_R, anc_ok, slot, t, nu, R, m):
    """Store the slot's last accepted row: time t, post-fit residual nu (m,), R (m, m)."""
    _put(anc_t, anc_nu, anc_R, slot, t, nu, R, m)
    anc_ok[slot] = True


@njit(cache=True)
def drift_nis_from_anchor(ring_t, ring_nu, ring_R, anc_t, anc_nu, anc_R, anc_ok, slot, count, degree, m):
    """NIS of the divided difference of order degree + 1 over the slot's last accepted row (its
    post-fit residual: where the filter's error stood after that update) and its degree + 1 last
    rejections (the last one number `count`): a filter's error drifts continuously from where the
    last accepted fix left it (a polynomial through the anchor), fixes that jumped do not (a step
    away from it). -1 when there are too few, no anchor, two share a time, or m = 1 (`drift_nis`)."""
    n = degree + 2
    if count + 1 < n - 1 or m < 2 or not anc_ok[slot]:
        return -1.0
    ts = np.empty(n)
    nus = np.empty((n, m))
    Rs = np.empty((n, m, m))
    # (row by row with `_put`: slice assignments compile numba's formatted shape-mismatch error, which the
    # filter's kernel then loads at every run)
    _put(ts, nus, Rs, 0, anc_t[slot], anc_nu[slot], anc_R[slot], m)
    for jj in range(1, n):
        j = (count - (jj - 1)) % WINDOW
        _put(ts, nus, Rs, jj, ring_t[slot, j], ring_nu[slot, j], ring_R[slot, j], m)
    return _divided_difference_nis(ts, nus, Rs, m)


@njit(cache=True)
def _nis_scaled(u, Ann, B, Aoo, R, nu, m, cross):
    """nu^T S(u)^-1 nu with S(u) = u^2 Ann + c (B + B^T) + Aoo + R, c = u if cross else 1; -1 if S is not PD."""
    c = u if cross else 1.0
    S = np.empty((m, m))
    for a in range(m):
        for b in range(m):
            S[a, b] = u * u * Ann[a, b] + c * (B[a, b] + B[b, a]) + Aoo[a, b] + R[a, b]
    return nis_into(nu, S, np.empty((m, m)), np.empty(m))


@njit(cache=True)
def _fit_factor(Ann, B, Aoo, R, nu, m, target, cross):
    """The smallest u in [1, _MAX_SQRT_LAMBDA] with nu^T S(u)^-1 nu <= target (`_nis_scaled`), by
    bisection on log u; 1 when u = 1 already fits."""
    if not _nis_scaled(1.0, Ann, B, Aoo, R, nu, m, cross) > target:
        return 1.0
    lo, hi = 1.0, _MAX_SQRT_LAMBDA
    if _nis_scaled(hi, Ann, B, Aoo, R, nu, m, cross) > target:
        return hi
    for _ in range(60):  # |hi - lo| / hi below 1e-12 within 60 halvings of the log interval
        mid = np.sqrt(lo * hi)
        s = _nis_scaled(mid, Ann, B, Aoo, R, nu, m, cross)
        if s > target or s < 0.0:
            lo = mid
        else:
            hi = mid
    return hi


@njit(cache=True)
def deweight_to_fit(P, H, R, nu, m, target):
    """Scale R in place by c >= 1, the smallest with nu^T (H P H^T + c R)^-1 nu = target; returns c.
    A fix whose slot has been rejected for long without agreeing rejections goes in so, its
    influence that of a fix at the gate's edge (a down-weighted fix, not a trusted one)."""
    A = _hph(P, H, m)
    zero = np.zeros((m, m))
    u = _fit_factor(R, zero, A, zero, nu, m, target, False)
    for a in range(m):
        for b in range(m):
            R[a, b] *= u * u
    return u * u


@njit(cache=True)
def inflate_to_fit(P, H, R, nu, m, target, jump):
    """Grow P's position and velocity block in place by the least lambda >= 1 with
    nu^T (H P H^T + R)^-1 nu <= target (bisection on sqrt(lambda)); returns lambda (1: P unchanged).
    H (m, n), R (m, m), nu (m,) the innovation. The two readings of the error re-acquired
    (`JUMP`, `DRIFT`; `fusion._kernels` tries both and keeps the one the next fixes favour):
    - drift (jump False): the error came the way the filter's model makes errors, through the
      attitude and the biases: P <- D P D with D = diag(sqrt(lambda) on the first N_INFLATED states,
      1 elsewhere) (the block's correlations, with each other and with the rest, kept: its cross
      terms grow by sqrt(lambda));
    - jump (jump True): an independent jump of position and velocity the model did not produce (an
      IMU knock, a slip of the fixes): P <- P + blockdiag((lambda - 1) P_nn, 0), the cross terms kept
      (the fix then turns the attitude and the biases no more than before the jump).
    P stays symmetric PSD either way."""
    n = P.shape[0]
    k0 = N_INFLATED
    Ann = np.zeros((m, m))  # H_n P_nn H_n^T (the inflated states)
    B = np.zeros((m, m))  # H_n P_no H_o^T (their covariance with the rest)
    Aoo = np.zeros((m, m))
    for a in range(m):
        for b in range(m):
            snn = 0.0
            sno = 0.0
            soo = 0.0
            for i in range(n):
                ha = H[a, i]
                if ha == 0.0:
                    continue
                for j in range(n):
                    hb = H[b, j]
                    if hb == 0.0:
                        continue
                    v = ha * P[i, j] * hb
                    if i < k0 and j < k0:
                        snn += v
                    elif i < k0:
                        sno += v
                    elif j >= k0:
                        soo += v
            Ann[a, b] = snn
            B[a, b] = sno
            Aoo[a, b] = soo
    u = _fit_factor(Ann, B, Aoo, R, nu, m, target, not jump)
    if u == 1.0:
        return 1.0
    for i in range(n):
        di = u if i < k0 else 1.0
        for j in range(n):
            dj = u if j < k0 else 1.0
            if jump and (i >= k0 or j >= k0):
                continue
            P[i, j] *= di * dj
    return u * u


@njit(cache=True)
def stated_factors(kind, sd_factor, f):
    """f (3,) <- the factors from a row's R to the fixes' stated accuracy: GPS positions
    sd_factor[[0, 0, 1]], GPS velocities sd_factor[[2, 2, 3]] (`FilterConfig.stated_sd_factor`),
    1 for every other kind (its R is what it states)."""
    for a in range(3):
        f[a] = 1.0
    if kind == Kind.GPS_POSITION:
        f[0], f[1], f[2] = sd_factor[0], sd_factor[0], sd_factor[1]
    elif kind == Kind.GPS_VELOCITY:
        f[0], f[1], f[2] = sd_factor[2], sd_factor[2], sd_factor[3]


@njit(cache=True)
def stated_R(R, f, m):
    """R <- F R F in place, F = diag(f): a row's covariance at its stated accuracy."""
    for a in range(m):
        for b in range(m):
            R[a, b] *= f[a] * f[b]


@njit(cache=True)
def nis_at_stated(P, H, R, nu, m, f):
    """nu^T (H P H^T + F R F)^-1 nu, F = diag(f): the innovation against the fixes' stated
    accuracy instead of the R the filter uses (matched to the fix-to-fix scatter, which leaves out
    an error the fixes share over minutes); -1 if not PD."""
    S = _hph(P, H, m)
    for a in range(m):
        for b in range(m):
            S[a, b] += f[a] * R[a, b] * f[b]
    return nis_into(nu, S, np.empty((m, m)), np.empty(m))


@njit(cache=True)
def _hph(P, H, m):
    """H P H^T (m, m), exactly symmetric: `filters.kalman.innovation_into` with x = z = 0 and R = 0."""
    n = P.shape[0]
    S = np.empty((m, m))
    innovation_into(np.zeros(n), P, np.zeros(m), H[:m], np.zeros((m, m)), np.empty(m), np.empty((m, n)), S)
    return S
