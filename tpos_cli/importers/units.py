"""Unit names accepted by the CSV mapping files, and their factors to the contract's units.

A column's unit also says whether it is a rate or an increment: gyro columns in `rad`/`deg` are
angle increments (dθ over the sample interval), accelerometer columns in `m/s` are velocity
increments (dv); the importer divides those by the sample interval (the contract's mean-rate
convention, docs/architecture.md "IMU sample convention").
"""

from __future__ import annotations

import math

from tpos_cli.frames.earth import G0_MPS2

# contract unit per quantity: rad/s, m/s², µT, deg, m, m/s
GYRO_RATE = {"rad/s": 1.0, "deg/s": math.pi / 180.0, "mrad/s": 1e-3, "deg/h": math.pi / 180.0 / 3600.0}
GYRO_INCREMENT = {"rad": 1.0, "deg": math.pi / 180.0, "mrad": 1e-3}
ACC_RATE = {"m/s2": 1.0, "m/s^2": 1.0, "m/s²": 1.0, "g": G0_MPS2, "mg": 1e-3 * G0_MPS2, "ug": 1e-6 * G0_MPS2}
ACC_INCREMENT = {"m/s": 1.0}
MAG = {"ut": 1.0, "µt": 1.0, "nt": 1e-3, "mt": 1e3, "t": 1e6, "gauss": 100.0, "mg": 0.1, "mgauss": 0.1}
ANGLE_DEG = {"deg": 1.0, "rad": 180.0 / math.pi}
LENGTH_M = {"m": 1.0, "mm": 1e-3, "cm": 1e-2, "km": 1e3, "ft": 0.3048}
SPEED_MPS = {"m/s": 1.0, "km/h": 1.0 / 3.6, "knots": 1852.0 / 3600.0, "kn": 1852.0 / 3600.0, "mm/s": 1e-3}
# time units of a plain counter / elapsed-time column, to seconds
TIME_S = {"s": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6, "ns": 1e-9}


def factor(table: dict[str, float], unit: str, what: str) -> float:
    """Factor that converts `unit` to the contract unit of `what`; KeyError names the choices."""
    key = unit.strip().lower() if table is MAG else unit.strip()
    if key not in table:
        raise KeyError(f"unit {unit!r} is not known for {what}; use one of {', '.join(table)}")
    return table[key]
