"""Forward-backward attitude smoothing of a local filter (tpos is a post-processor).

The same kernel runs forward and, on time-reversed samples, backward (`local.run_full`); the two
estimates are combined on SO(3) with their covariances (two-filter smoother, Fraser-Potter form),
which is exactly the information fusion of Eq. 27 applied to the two runs (`master.fuse`).
The backward run starts from the forward run's last attitude and bias with a wide attitude
covariance (`back_sd_rad`), so that the two runs are practically independent.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from tpos_cli.attitude import master
from tpos_cli.attitude.local import AttitudeSolution, FilterSetup, run_full


def smooth_full(name, t_s, gyro_b_rps, acc_b_mps2, mag_b_ut, rdiff_m, setup: FilterSetup, use: int,
                back_sd_rad: float = np.radians(5.0), forward: AttitudeSolution | None = None,
                still=None) -> AttitudeSolution:
    """Smoothed `run_full` solution; `nis` are the forward run's, `mag_ok` is True where both runs
    accepted the field. `forward` may pass an already computed forward run with the same setup."""
    fwd = forward if forward is not None else run_full(name, t_s, gyro_b_rps, acc_b_mps2, mag_b_ut, rdiff_m, setup, use, still=still)
    P0 = np.array(setup.P0, dtype=float)
    P0[0:3, 0:3] = np.eye(3) * back_sd_rad**2 * setup.beta  # run_full divides P0 by beta
    bsetup = replace(setup, C0=fwd.C_nb[-1], bias0_rps=fwd.bias_rps[-1], P0=P0)
    if fwd.gyro_M is not None:
        bsetup = replace(bsetup, gyro_M0=fwd.gyro_M[-1])
    bwd = run_full(name, t_s, gyro_b_rps, acc_b_mps2, mag_b_ut, rdiff_m, bsetup, use, backward=True, still=still)
    s = master.fuse(name, [fwd, bwd])
    mag_ok = None if fwd.mag_ok is None else (fwd.mag_ok & bwd.mag_ok)
    return AttitudeSolution(name=name, t_s=fwd.t_s, C_nb=s.C_nb, P_att=s.P_att,
                            bias_rps=0.5 * (fwd.bias_rps + bwd.bias_rps), nis=fwd.nis, mag_ok=mag_ok,
                            mag_gated=fwd.mag_gated)
