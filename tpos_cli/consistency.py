"""Consistency statistics of a filter against its own covariances: pure functions, no tables.

A consistent Kalman filter's normalized innovation squared NIS = ν^T S^-1 ν of a d-dimensional
update is chi-square with d degrees of freedom, and successive innovations are independent
(Bar-Shalom, Li & Kirubarajan 2001, sec. 5.4); the normalized estimation error squared NEES against
truth is chi-square with the state dimension. The tests here ask whether a run's figures are
plausible under that hypothesis, with bands from the distributions, never from measured values:

- the mean NIS of n updates: the sum of n chi-square(d_i) is chi-square(Σ d_i), so the mean lies in
  chi2.ppf([α/2, 1-α/2], Σd)/n. Updates that passed a chi-square gate at probability g are a
  truncated chi-square, E = d F_{d+2}(c)/F_d(c), E[X²] = d(d+2) F_{d+4}(c)/F_d(c) with c =
  chi2.ppf(g, d) (moments of a truncated gamma); their sum is approximated by the gamma of the
  same mean and variance, which is exact (chi-square) when nothing is truncated.
- rejections: each update is rejected with probability 1 - g under the hypothesis, so the count is
  binomial; a Clopper-Pearson bound (Clopper & Pearson 1934) says how large the true rate must at
  least be.
- serially correlated statistics (epochs of a smoothed trajectory, updates at the IMU rate): the mean
  of n correlated values varies as that of n / τ independent ones, τ = 1 + 2 Σ_k ρ_k the integrated
  autocorrelation time (Bayley & Hammersley 1946), estimated with Sokal's automatic window (Sokal 1997,
  sec. 3; Goodman & Weare 2010): an AR(1) series has τ = (1 + ρ1) / (1 - ρ1), but a series with a slow
  component beside a fast one (a filter's innovations against a field or a motion its model does not
  hold) has a lag-1 ρ1 set by the fast part, and n (1 - ρ1) / (1 + ρ1) overstates its information
  (`effective_sample_size` takes the larger of the two readings).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from scipy import special  # the distributions' functions: scipy.stats costs about a second to import

SUSPECT_PROB = 0.999  # two-sided bands: a consistent run falls outside one with probability 0.1 %


def truncated_chi2_moments(dof: float, gate_probability: float | None = None) -> tuple[float, float]:
    """Mean and variance of chi-square(dof) conditioned on being below chi2.ppf(gate_probability, dof)."""
    if gate_probability is None or gate_probability >= 1.0:
        return float(dof), 2.0 * float(dof)
    c = special.chdtri(dof, 1.0 - gate_probability)  # chi2.ppf
    f0 = special.chdtr(dof, c)
    m1 = dof * special.chdtr(dof + 2, c) / f0
    m2 = dof * (dof + 2) * special.chdtr(dof + 4, c) / f0
    return float(m1), float(max(m2 - m1 * m1, 1e-300))


def mean_nis_band(dof, gate_probability: float | None = None, prob: float = SUSPECT_PROB) -> tuple[float, float, float]:
    """(expected, lo, hi): the two-sided `prob` band of the mean NIS of updates with d.o.f. `dof` (n,)
    that passed a gate at `gate_probability` (None: ungated)."""
    d = np.asarray(dof, dtype=float).ravel()
    n = d.size
    if n == 0:
        nan = float("nan")
        return nan, nan, nan
    mom = np.array([truncated_chi2_moments(v, gate_probability) for v in np.unique(d)])
    counts = np.array([(d == v).sum() for v in np.unique(d)])
    mean = float((mom[:, 0] * counts).sum())  # of the sum
    var = float((mom[:, 1] * counts).sum())
    shape, scale = mean * mean / var, var / mean  # gamma with the sum's mean and variance
    a = (1.0 - prob) / 2.0
    lo, hi = special.gammaincinv(shape, np.array([a, 1.0 - a])) * scale  # gamma.ppf
    return mean / n, float(lo) / n, float(hi) / n


def binomial_excess(k: int, n: int, p0: float) -> float:
    """One-sided p-value P(X >= k) for X ~ Binomial(n, p0): how unlikely so many events are."""
    if n <= 0 or k <= 0:
        return 1.0
    return float(special.bdtrc(k - 1, n, p0))  # binom.sf


def rate_lower_bound(k: int, n: int, prob: float = SUSPECT_PROB) -> float:
    """One-sided Clopper-Pearson lower bound on a binomial rate (0 when k = 0)."""
    if n <= 0 or k <= 0:
        return 0.0
    return float(special.betaincinv(k, n - k + 1, 1.0 - prob))  # beta.ppf


def integrated_time(x, c: float = 5.0) -> float:
    """Integrated autocorrelation time τ = 1 + 2 Σ_{k=1}^{M} ρ_k (samples, >= 1) of a series (NaN dropped),
    summed up to Sokal's automatic window M, the smallest with M >= c τ(M) (Sokal 1997, sec. 3; c = 5
    keeps the truncation bias below e^-5 of τ for an exponential correlation, and the estimate's relative
    SD is about sqrt(2 (2M + 1) / n)). The autocovariance is taken by FFT (Wiener-Khinchin, zero-padded)."""
    v = np.asarray(x, dtype=float).ravel()
    v = v[np.isfinite(v)]
    n = v.size
    if n < 3:
        return 1.0
    d = v - v.mean()
    f = np.fft.rfft(d, 2 * n)
    acf = np.fft.irfft(f * np.conj(f), 2 * n)[:n]
    if acf[0] <= 0.0:
        return float(n)  # a constant series: one value's worth
    taus = 2.0 * np.cumsum(acf / acf[0]) - 1.0
    short = np.arange(n) < c * taus
    m = int(np.argmin(short)) if not short.all() else n - 1
    return float(np.clip(taus[m], 1.0, n))


def effective_sample_size(x) -> float:
    """Effective number of independent samples n / τ of a series (n when uncorrelated, >= 1), τ the larger of
    two readings of its correlation: the AR(1) one, (1 + ρ1) / (1 - ρ1) from the lag-1 correlation, and the
    windowed sum (`integrated_time`). Each misses what the other sees: the lag-1 reading a slow component
    beside a fast one, the windowed sum a correlation longer than a short series can show (a few long runs
    of flags in 1000 epochs: its window stops where the estimated correlations of a short series turn
    negative). Under-reading τ makes a consistent run's mean fall outside its band more often than the
    band's probability says (false alarms); over-reading it widens the band, which costs the test power
    against a small misstatement but never calls a consistent run wrong: the larger reading is taken."""
    v = np.asarray(x, dtype=float).ravel()
    v = v[np.isfinite(v)]
    n = v.size
    if n < 3:
        return float(n)
    d = v - v.mean()
    den = float(d @ d)
    if den <= 0:
        return 1.0
    rho = float(np.clip((d[1:] @ d[:-1]) / den, 0.0, 0.999999))
    tau = max((1.0 + rho) / (1.0 - rho), integrated_time(v))
    return float(np.clip(n / tau, 1.0, n))


@dataclass(frozen=True)
class MeanChi2:
    """A mean of chi-square statistics against its band: `ratio` = mean / expected (1 if consistent;
    its square root is how many times the errors exceed their sigmas)."""

    n: int
    dof: float  # median d.o.f. of one statistic
    mean: float
    expected: float
    lo: float
    hi: float
    ratio: float
    inside: bool

    def as_dict(self) -> dict:
        return asdict(self)


def mean_chi2(values, dof, *, gate_probability: float | None = None, n_eff: float | None = None,
              prob: float = SUSPECT_PROB, model_rel_sd: float = 0.0) -> MeanChi2:
    """The mean of chi-square statistics `values` (n,) with d.o.f. `dof` (scalar or (n,)) against its
    band. `n_eff` < n widens the band for serially correlated values (the band of n_eff values of
    the median d.o.f.). `model_rel_sd`: relative SD of the noise variances the statistics were
    normalized by, when those were themselves estimated (a calibration of N pairs: sqrt(2 / N));
    the expected mean is then uncertain by that share, added in quadrature to the band's half-widths
    at the same probability (a long log's band would otherwise be narrower than its noise model
    is known)."""
    x = np.asarray(values, dtype=float).ravel()
    d = np.broadcast_to(np.asarray(dof, dtype=float), x.shape)
    ok = np.isfinite(x) & np.isfinite(d) & (d > 0)
    x, d = x[ok], d[ok]
    n = int(x.size)
    if n == 0:
        nan = float("nan")
        return MeanChi2(0, nan, nan, nan, nan, nan, nan, True)
    if n_eff is not None and n_eff < n:
        m = max(1, int(round(n_eff)))
        d_band = np.full(m, float(np.median(d)))
    else:
        d_band = d
    exp, lo, hi = mean_nis_band(d_band, gate_probability, prob)
    if n_eff is not None and n_eff < n:
        exp = mean_nis_band(d, gate_probability, prob)[0]
    if model_rel_sd > 0:
        z = float(-special.ndtri(0.5 * (1.0 - prob)))
        lo = exp - float(np.hypot(exp - lo, z * model_rel_sd * exp))
        hi = exp + float(np.hypot(hi - exp, z * model_rel_sd * exp))
    mean = float(x.mean())
    return MeanChi2(n, float(np.median(d)), mean, exp, lo, hi, mean / exp, bool(lo <= mean <= hi))


def separation_chi2(diff, var_a, var_b) -> np.ndarray:
    """Per-epoch d^T (P_a + P_b)^-1 d with diagonal variances (n, k): chi-square(k) when the two
    estimates are independent and both consistent (two runs sharing data disagree less)."""
    d = np.asarray(diff, dtype=float)
    v = np.asarray(var_a, dtype=float) + np.asarray(var_b, dtype=float)
    with np.errstate(invalid="ignore", divide="ignore"):
        q = np.where(v > 0, d * d / v, np.nan)
    return np.sum(q, axis=1)


def block_log_ratio_z(base, cand, *, min_block: int = 10, max_blocks: int = 30) -> float:
    """Whether the positive series `cand` (n,) is smaller than `base` (n,), paired and in time
    order, as a z-score (> 0: cand smaller).

    Batch means (Schmeiser 1982: 10-30 batches): the series are cut into B contiguous blocks of at
    least `min_block` values; per block the log of the ratio of the sums, which is well-behaved
    even when single values are heavy-tailed (squared prediction errors) and, over blocks longer
    than the serial correlation, independent; their mean is tested with Student's t (B - 1 dof),
    whose one-sided p-value is returned as the equivalent normal z."""
    b = np.asarray(base, dtype=float).ravel()
    c = np.asarray(cand, dtype=float).ravel()
    ok = np.isfinite(b) & np.isfinite(c)
    b, c = b[ok], c[ok]
    n_blocks = int(min(max_blocks, b.size // min_block))
    if n_blocks < 3:
        return 0.0
    lr = np.array([np.log(max(float(y.sum()), 1e-300) / max(float(x.sum()), 1e-300))
                   for x, y in zip(np.array_split(b, n_blocks), np.array_split(c, n_blocks))])
    sd = float(lr.std(ddof=1))
    if not sd > 0:
        return float(np.sign(-lr.mean()) * np.inf) if lr.mean() != 0 else 0.0
    t = -float(lr.mean()) / (sd / np.sqrt(n_blocks))
    return float(-special.ndtri(special.stdtr(n_blocks - 1, -t)))  # norm.isf(t.sf)
