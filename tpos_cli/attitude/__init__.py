"""Attitude estimation of the target-positioning paper 000: DCM local filters and the federated master.

- `local`: gyro-only, LF1 (accelerometer/magnetometer, Eq. 5-9, 16-22) and LF2 (three laser
  rangefinders, Eq. 10-15, 16-22), in the full-attitude model (default) or the paper's 8-state one;
- `master`: the no-reset federated fusion (Eq. 23-27);
- `faults`: local-filter fault detection that feeds the master's weights.
"""
