"""Chi-square innovation gating: thresholds computed once with scipy, compared in kernels."""

from __future__ import annotations

import numpy as np


def chi2_threshold(probability: float, dof_max: int) -> np.ndarray:
    """Array `g` with g[m] = chi-square quantile for `probability` at m degrees of freedom.

    g[0] is +inf so that index = measurement dimension inside a kernel. Innovations with
    NIS > g[m] are rejected (counted, not applied).
    """
    from scipy.special import (
        chdtri,  # not scipy.stats: its import alone costs 0.5 s of `tpos process`
    )

    if not 0.0 < probability < 1.0:
        raise ValueError(f"`probability` must be in (0, 1), got {probability}")
    g = np.full(dof_max + 1, np.inf)
    g[1:] = chdtri(np.arange(1, dof_max + 1), 1.0 - probability)  # = chi2.ppf(probability, dof)
    return g
