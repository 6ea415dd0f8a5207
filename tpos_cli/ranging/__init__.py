"""Ranging to anchors at known positions (paper 002: FATCI).

- `calibration`: range error model d~ = f d + c (Eq. 13-16), least-squares fit and correction;
- `fuzzy`: the SISO fuzzy inference that scales each range's R (Eq. 31, Algorithm 1);
- `multilateration`: least-squares position fix from one epoch's ranges (loosely coupled input);
- `measurements`: range and position measurement models with their Jacobians (Eq. 19-24);
- `filter`: the loosely / tightly coupled INS/range filters built on `fusion`.
"""
