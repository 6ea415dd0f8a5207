"""Offsets of the 15-state navigation error vector (paper 003 Sec. 4.2 order)."""

POS = 0  # position error, NED metres
VEL = 3  # velocity error, NED m/s
ATT = 6  # attitude error phi, rad: C_nb_est = (I - [phi x]) C_nb_true
BA = 9  # accelerometer bias error, m/s^2 (body)
BG = 12  # gyro bias error, rad/s (body)
N_NAV = 15
