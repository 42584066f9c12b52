"""
The raw-IMU estimator's flat state, declared once: ``AHRS``'s fields in order.

Parameters (``P_``, set once by the wrapper from :class:`AhrsParams`),
coefficients of the current intervals (``C_``, NaN until computed) and the
estimate with what it remembers (``S_``); the magnetometer calibration's
block follows at ``MC0`` (:mod:`~ext_observer.core.ahrs.magcal_layout`).
The offsets are computed (:mod:`~ext_observer.core.ahrs.layout`).
"""

from .layout import Layout

# --- the layout ----------------------------------------------------------------

AHRS = Layout()
# Parameters: AhrsParams's of the same name (set once by the wrapper).
P_ALPHA = AHRS.parameter('alpha')
P_TAU_ACC = AHRS.parameter('tau_acc')
P_TAU_ACC_GAIN = AHRS.parameter('tau_acc_gain')
P_TAU_MAG = AHRS.parameter('tau_mag')
P_TAU_BIAS = AHRS.parameter('tau_bias')
P_BIAS_MAX = AHRS.parameter('bias_max')
P_REST_GYR = AHRS.parameter('rest_gyr')
P_REST_ACC = AHRS.parameter('rest_acc')
P_REST_TIME = AHRS.parameter('rest_time')
P_TAU_REST = AHRS.parameter('tau_rest')
P_MAG_NORM_TH = AHRS.parameter('mag_norm_th')
P_MAG_DIP_TH = AHRS.parameter('mag_dip_th')
P_MAG_NEW_TIME = AHRS.parameter('mag_new_time')
P_MAG_NEW_GYR = AHRS.parameter('mag_new_gyr')
P_TAU_MAG_REF = AHRS.parameter('tau_mag_ref')
# Parameters the wrapper derives.
P_USE_MAG = AHRS.field('use_mag')
P_EXTENDED = AHRS.field('extended')  # variant 'extended' (1) or 'plain' (0)
P_HAS_CAL = AHRS.field('has_cal')  # a magnetometer calibration runs (mag_cal and 9D)
P_CAL_PERIOD = AHRS.field('cal_period')  # s: learn from a field at most this often
P_MOTION_BIAS = AHRS.field('motion_bias')  # tau_bias > 0
# Coefficients of the current intervals (NaN: not computed yet).
C_DT = AHRS.field('dt')
C_BW = AHRS.field('bw', 5)  # b0, b1, b2, a1, a2
C_K_ACC = AHRS.field('k_acc')
C_K_REST = AHRS.field('k_rest')
C_MAG_DT = AHRS.field('mag_dt')
C_K_MAG = AHRS.field('k_mag')
C_K_REF = AHRS.field('k_ref')
# The estimate and what it remembers.
S_INIT = AHRS.field('init')
S_Q = AHRS.field('q', 4)
S_BIAS = AHRS.field('bias', 3)
S_REST = AHRS.field('rest')
S_REST_TIME = AHRS.field('time_at_rest')
S_REST_GYR = AHRS.field('rest_gyr_lp', 3)
S_REST_ACC = AHRS.field('rest_acc_lp', 3)
S_LP = AHRS.field('lp', 6)  # the Butterworth states s1 (3), s2 (3)
S_ACC_STILL = AHRS.field('acc_still')
S_MAG_DIST = AHRS.field('mag_dist')
S_HAS_REF = AHRS.field('has_ref')
S_REF = AHRS.field('ref', 2)  # norm, dip
S_CAND = AHRS.field('cand', 2)  # norm, dip of a new field
S_CAND_TIME = AHRS.field('cand_time')
S_MAG_USED = AHRS.field('mag_used')
S_CAL_TURN = AHRS.field('cal_turn', 4)  # body rotation since the field last learned from
S_CAL_RATE = AHRS.field('cal_rate', 3)  # the latest angular rate, bias removed
S_CAL_WAIT = AHRS.field('cal_wait')
S_CAL_MOVED = AHRS.field('cal_moved')
S_CAL_SINCE = AHRS.field('cal_since')
S_CAL_LOADED = AHRS.field('cal_loaded')
# --- where the robot starts: the bias in motion, the start, a clipped gyro ---------
P_BIAS_SIGMA_INIT = AHRS.parameter('bias_sigma_init')  # rad/s: σ of the bias at first
P_BIAS_SIGMA_MOTION = AHRS.parameter('bias_sigma_motion')  # rad/s: in steady motion
P_GYRO_RANGE = AHRS.parameter('gyro_range')  # rad/s: the gyro's range (0: unknown)
C_BIAS_Q = AHRS.field('bias_q')  # rad²/s²: the bias's random walk per sample
C_BIAS_R = AHRS.field('bias_r')  # (rad/s)²·s: noise density of a correction rate
S_BIAS_P = AHRS.field('bias_p', 6)  # the bias's covariance, xx xy xz yy yz zz
# The per-axis variances' offsets in S_BIAS_P (the upper triangle, packed by rows).
BIAS_P_XX = 0
BIAS_P_YY = 3
BIAS_P_ZZ = 5
BIAS_P_DIAGONAL = (BIAS_P_XX, BIAS_P_YY, BIAS_P_ZZ)
S_RLP = AHRS.field('r_lp', 18)  # Butterworth states of R(q̂) (s1 9, s2 9), rows x, y, z
S_RZLP = AHRS.field('rz_lp', 3)  # R(q̂)'s z row low-passed by the heading correction
S_START = AHRS.field('start')  # s since the start (or a clipped stretch)
S_START_N = AHRS.field('start_n')  # samples in the running mean
S_CLIPS = AHRS.field('clips')  # clipped samples counted
S_CLIPPED = AHRS.field('clipped')  # the last sample's clipped variance (0: not clipped)
S_GYR_LAST = AHRS.field('gyr_last', 3)  # the previous sample's rate, as measured
S_GYR_PEAK = AHRS.field('gyr_peak')  # largest |rate| on any axis seen
S_STUCK = AHRS.field('stuck', 3)  # samples each axis has repeated its rate at the peak
S_REF_AGE = AHRS.field('ref_age')  # s of fields that confirmed the field references
S_REJECTED = AHRS.field('rejected')  # s the field has been rejected as disturbed without a break
# While the heading waits for the calibration: the turn (rad) the fields of
# the wait would have given it, had they been used as given, and their count.
S_WAIT_TURN = AHRS.field('wait_turn')
S_WAIT_N = AHRS.field('wait_n')
S_REF_REST = AHRS.field('ref_rest')  # 1: fields at rest have confirmed the field references
# A hole in the stream (hole_kernel): an interval much longer than the usual one.
S_HOLE_RUN = AHRS.field('hole_run')  # s of holes in a row (longer: the rate changed)
S_HOLE_VAR = AHRS.field('hole_var')  # rad² per axis the last step's hole adds (0: none)
S_HOLES = AHRS.field('holes')  # holes bridged
S_HOLE_T0 = AHRS.field('hole_t0')  # s the inclination's restarted mean weighs the old as (−1: kept)
S_ACC_DEV = AHRS.field('acc_dev')  # the specific force's recent deviation from gravity, (1/g)²
S_GYR_PREV = AHRS.field('gyr_prev', 3)  # the rate of the sample before S_GYR_LAST
# The end correction a hole leaves for the next usual sample: T²/12 over the
# usual interval (0: none), and the rate's change into the hole.
S_HOLE_END = AHRS.field('hole_end', 4)
# rad: the inclination's error σ that holes and clipped samples left beyond the
# usual, forgotten at the low-pass's pace (0: none).
S_INC_SIGMA = AHRS.field('inc_sigma')
S_STEPS = AHRS.field('steps')  # the usual steps this sample stands for (a hole's: more than 1)
S_CLIP_LEFT = AHRS.field('clip_left')  # s of the recovery from a clipped sample still to run

# The velocity aid (velocity_kernel): the body's velocity at the IMU, IMU frame.
P_VEL_TIMEOUT = AHRS.field('velocity_timeout')  # s: an older velocity is not used
S_VEL = AHRS.field('vel', 3)  # m/s: the latest velocity
S_VEL_DV = AHRS.field('vel_dv', 3)  # m/s²: its derivative over the latest interval
S_VEL_N = AHRS.field('vel_n')  # velocities taken since the last gap (2: a derivative)
S_VEL_AGE = AHRS.field('vel_age')  # s of IMU steps since the latest velocity
S_VEL_ACC = AHRS.field('vel_acc', 3)  # m/s²: the kinematic acceleration of this step
S_VEL_USED = AHRS.field('vel_used')  # 1: this step's specific force had it removed

# Acceleration rejection (accel_rejection).
P_ACC_REJECT = AHRS.parameter('acc_reject')  # rad: a low-passed force this far from u is rejected
P_ACC_REJECT_TIME = AHRS.parameter('acc_reject_time')  # s: the longest rejection
S_ACC_CARRIED = AHRS.field('acc_carried', 3)  # u: the vertical the gyro carries, world frame
S_ACC_REJ = AHRS.field('acc_rej')  # s the force has been rejected (0: used)
S_ACC_TILT = AHRS.field('acc_tilt')  # rad/s: the recent rate of tilting rotation
# The field step after a clipped gyro or a hole (field_kernel): what the gyro lost.
S_HEAD_DOUBT = AHRS.field('head_doubt')  # rad²: heading variance no field has corrected yet
S_TILT_DOUBT = AHRS.field('tilt_doubt')  # rad²: its share of tilt, as the accelerometer forgets it
S_FIELD_CLIPPED = AHRS.field('field_clipped')  # 1: the gyro clipped since the latest field
S_DOUBT_GAIN = AHRS.field('doubt_gain')  # the latest field's gain where the doubt raised it, else 0
A_SIZE = AHRS.size
MC0 = A_SIZE  # the calibration's block starts here

PARAMETERS = tuple(AHRS.parameters)
