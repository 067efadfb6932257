"""Physical and protocol constants sarbot uses in more than one place."""

#: Speed of light in vacuum, m/s.
SPEED_OF_LIGHT_MPS = 299_792_458.0

#: Standard gravity, m/s^2 (the IMU simulator and the EKF's gravity vector agree on it).
GRAVITY_MPS2 = 9.80665

#: TAI - UTC since 2017-01-01: PTP time (TAI) = CLOCK_REALTIME (UTC) + this.
TAI_MINUS_UTC_NS = 37_000_000_000

#: 99.9 % quantiles of the chi-square distribution by degrees of freedom: the EKF's and the ego-velocity
#: solver's gates.
CHI2_999 = {1: 10.83, 2: 13.82, 3: 16.27}

#: Arbitration id of the sync box's trigger frame on CAN (its payload: the trigger's PTP time, u64 LE).
CAN_TRIGGER_ID = 0x100

#: How backprojection samples a range profile (imaging.backprojection): nearest bin, linear interpolation, or
#: the exact matched filter. Here, not in the kernels' module, so that options are checked without importing
#: numba (image formation's and the strip map's configurations).
BACKPROJECTION_MODES = ("nearest", "linear", "exact")
