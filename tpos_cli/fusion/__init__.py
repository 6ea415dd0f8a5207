"""Navigation error-state filters: the 15-state INS/GPS filter of paper 003, forward and backward.

Error state (paper 003 Sec. 4.2 order, offsets in `tpos_cli.fusion.layout`):
`x = [dp_ned_m (POS=0), dv_ned_mps (VEL=3), phi_rad (ATT=6), dba_mps2 (BA=9), dbg_rps (BG=12)]`,
every error being estimate minus truth; `phi` is the small rotation with
`C_nb_est = (I - [phi x]) C_nb_true`. Extra states (e.g. one range bias per anchor) go after
index 15 (`N_NAV = 15`). Measurements are `z = h(INS) - measured` (paper Eq. 12), so `H x` predicts
them. The filter is closed loop: after each update the estimate is fed back into the nominal
state and reset to zero (paper Fig. 1).

How another filter (e.g. the tightly coupled INS/anchor-range filter in `tpos_cli.ranging`)
reuses the pieces, all `@njit(cache=True)` functions callable from its own numba loop:

- `tpos_cli.ins._kernels.mech_step(nav, C, dtheta, dv, dtheta_prev, dv_prev, dt, earth_sign, f_n)`
  advances the nominal state in place (`nav` = [lat_rad, lon_rad, h_m, vn, ve, vd], `C` = C_nb).
  Correct the IMU increments with the nominal biases first: `nav_errors.corrected_increments`.
- `tpos_cli.fusion.nav_errors.error_dynamics(nav, C, f_n, earth_sign, tau_acc_s, tau_gyro_s, F)`
  writes the 15x15 block of F into `F[:15, :15]` of an (n, n) array (leave the rest zero, or set the
  extra states' own dynamics, e.g. 0 for a constant range bias); `f_n` is the mean specific force
  in NED over the covariance step (sum `mech_step`'s `f_n` * dt and divide). `nav_errors.process_noise(
  q, Qc)` writes the continuous noise PSDs on the diagonal of Qc[:15, :15], `q` (4,) = [acc white,
  gyro white, acc-bias drive, gyro-bias drive] (see `fusion.insgps.FilterConfig`).
- `tpos_cli.filters.kalman.discretize(F, Qc, dt, Phi, Qd)`, `predict(x, P, Phi, Qd)`,
  `update(x, P, z, H, R) -> nis` work for any n and m, in place. Gate with `nis_of(...)` first
  against `tpos_cli.filters.gating.chi2_threshold(prob, m_max)[m]`.
- `nav_errors.apply_feedback(nav, C, bias, x)` applies `x[:15]` to the nominal state and the
  bias estimates `bias` (6,) = [acc (3), gyro (3)]; then set `x[:] = 0` (extra states such as
  anchor biases are the caller's to feed back).
- `nav_errors.position_jacobian(nav, C, lever_b, lag_s, H, row)` fills H rows for a NED antenna
  or node position (`position_residual` gives z); a range to a known point p_a is
  `r = |p_a - p|` with `H[0, 0:3] = -(p_a - p) / r` in NED metres at the node (chain rule through
  `position_jacobian` for a lever arm), plus 1 in the anchor-bias column.
- Backward (paper 003's reversed time): feed `tpos_cli.ins.reverse_imu(t, gyro, acc)`, negate the
  nominal velocity, pass `earth_sign = -1.0` to `mech_step` and `error_dynamics`; the backward
  error state relates to the forward one by `nav_errors.backward_sign()` (velocity and gyro bias
  flip sign).

Time-correlated GPS errors: with an 18 x 18 P0 (`FilterConfig.gps_gm_sigma_ned_m`, `gps_gm_tau_s`)
`insgps_kernel` carries three Gauss-Markov GPS position-error states (x[15:18], nominal in
bias[6:9]); `tpos_cli.fusion.gps_error.fit_gps_error` sizes them by maximum likelihood of the
innovations, keeping them only when a likelihood-ratio test rejects white fixes. The smoothers
take 15 or 18 states.

`tpos_cli.fusion.gps_noise.estimate_gps_noise` scales the GPS SDs by covariance matching on
decimated forward passes (the kernel's per-fix `innovation_pvar` = diag H P- H^T), and
`tpos_cli.fusion.mounting` checks course over ground against yaw for land vehicles.

`tpos_cli.fusion.insgps.run_insgps(...)` is the INS/GPS loop built from these pieces; its
compiled loop `tpos_cli.fusion._kernels.insgps_kernel` is the worked example to follow (epochs
every `cov_step` samples and at each measurement; RTS history stored per epoch), and
`tpos_cli.smoothing` (rts_closed_loop, two_filter, simplified) works on any run that stores
the same per-epoch arrays (`FilterRun`).
"""
