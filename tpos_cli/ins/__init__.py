"""Strapdown inertial mechanization on WGS-84: `mech_step` numba kernel (in `_kernels`) and wrappers."""

from tpos_cli.ins.mechanization import InsTrajectory, integrate, nav_vector, reverse_imu

__all__ = ["InsTrajectory", "integrate", "nav_vector", "reverse_imu"]
