"""Generic Kalman-filter algebra: numba kernels over (x, P, Phi, Qd, H, R, z), chi-square gating.

Knows nothing about navigation; `tpos_cli.fusion` builds the navigation models on top.
"""

from tpos_cli.filters.gating import chi2_threshold
from tpos_cli.filters.kalman import discretize, predict, update

__all__ = ["chi2_threshold", "discretize", "predict", "update"]
