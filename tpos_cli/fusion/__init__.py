"""The INS error-state filter of every chain (paper 003; paper 002's INS/range filters), forward and backward.

Error state (paper 003 Sec. 4.2 order, `fusion.layout`): `x = [dp_ned_m (POS=0), dv_ned_mps (VEL=3),
phi_rad (ATT=6), dba_mps2 (BA=9), dbg_rps (BG=12)]`, every error being estimate minus truth; `phi`
is the small rotation with `C_nb_est = (I - [phi x]) C_nb_true`; then optional blocks of extra
states (`layout.Block`: GPS error, range bias, floor height, anchor calibration). Measurements are
`z = h(INS) - measured` (paper Eq. 12), so `H x` predicts them. The filter is closed loop: after
each update the estimate is fed back into the nominal state and reset to zero (paper Fig. 1).

Where each piece lives:
- `layout`: state offsets, extra-state blocks (`StateLayout`), backward-time signs;
- `nav_errors`: the 15-state error dynamics F, process noise, feedback into the nominal;
- `measurements`: `Kind` (IntEnum) and one @njit residual/Jacobian pair per kind, dispatched by
  `measure`;
- `_kernels`: the one compiled loop (`error_state_kernel`) over named tuples of arrays;
- `engine`: `FilterConfig`, `InitialState`, `Measurements`, `FilterRun`, `run_filter` (the
  documented wrapper, forward and backward), `backward_start`, `epoch_of`;
- `insgps`: GPS fixes as measurements (`run_insgps`, `gps_innovations`); `initial`: alignment and
  yaw search of a land vehicle; `gps_noise`, `gps_error`: GPS noise and error-state fitting;
  `mounting`: the course-minus-yaw check and the vehicle's attitude; `lever_arm`: when to estimate
  a correction to the stated GPS lever arm, and the output at the stated point.
`tpos_cli.smoothing` (rts, two_filter, simplified) works on any `FilterRun`; `tpos_cli.trajectory`
turns its solutions into contract rows.

Extending it (issue 11):
- a new measurement kind (ZUPT/ZARU of a vehicle, non-holonomic constraints, odometer speed): one
  `measurements.Kind` member, one `*_residual` / `*_jacobian` pair with a finite-difference test,
  one branch in `measurements.measure`, and a builder of its `engine.Measurements` rows (see
  `insgps.gps_measurements`, `ranging.filter.zupt_events`); the kernel needs no change;
- a new state (lever arm, IMU-GPS clock offset, odometer scale, residual mounting misalignment):
  one `layout.Block` member and an `ExtraBlock` builder (size, Gauss-Markov time constant or
  random walk / constant, driving PSD, prior), placed in `FilterConfig.layout`; the measurement
  kinds that depend on it read its offset (`lay[Block.X]`, -1 when absent) and its nominal in
  `bias[6 + offset - 15]`. Its feedback, propagation, backward run and smoothing come with the
  layout.
"""
