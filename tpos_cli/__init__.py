"""tpos: post-processing of navigation logs from low-cost sensors.

Conventions used throughout the package (the session contract is `docs/log-format.md`):

- Navigation frame NED; body frame FRD (x forward, y right, z down). Sensor vectors are rotated from
  the session's logged `[imu] axes` into FRD once, when the session is loaded.
- `C_nb` maps body vectors to navigation vectors; Euler angles roll, pitch, yaw with
  `C_nb = Rz(yaw) Ry(pitch) Rx(roll)`; yaw clockwise from true north. Radians inside, degrees in tables.
- Time: `t_s` is float64 seconds relative to the session epoch `Session.t0_s` (the logger-clock time of
  the first IMU sample); tables written for users carry `t` on the logger clock.
- Geodetic positions are WGS-84 `(lat_deg, lon_deg, h_m)` rows of `(N, 3)` arrays.
- Units in names: `_m`, `_mps`, `_mps2`, `_rad`, `_deg`, `_rps`, `_s`, `_ut`.
"""

__version__ = "0.1.0"
