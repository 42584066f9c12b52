"""
The raw-IMU estimator's state: its groups, each declared beside the code that owns it.

``STATE`` is what one estimate keeps (:mod:`~ext_observer.core.ahrs.record`):
the parameters (``par``, set once by the wrapper), the coefficients of the
current intervals (``coef``) and the estimate with what it remembers, one
group per concept, then the magnetometer calibration's state (``cal``,
:mod:`~ext_observer.core.ahrs.magcal_layout`'s ``CAL``). A
kernel reads ``s.rest.time`` or ``s.bias.rate[0]``; docs/layout.md lists
every field with its unit and meaning (``python -m ext_observer.core.ahrs.ahrs_state``
prints the table).
"""

from .accel_rejection import REJ
from .ahrs_kernel import COEF, EST
from .ahrs_params import AHRS_TABLE
from .bias_kernel import BIAS
from .clip_and_rest import GYRO, REST
from .field_kernel import CAL_FEED, FIELD
from .gravity_kernel import INC
from .hole_kernel import HOLE
from .magcal_layout import CAL
from .record import Group
from .velocity_kernel import VEL

__all__ = ['KERNEL_PARAMETERS', 'PAR', 'STATE']

# The AhrsParams the kernels read, by the same name (the calibration's are its own).
KERNEL_PARAMETERS = ('alpha', 'tau_acc', 'tau_acc_gain', 'tau_mag', 'tau_bias', 'bias_max',
                     'rest_gyr', 'rest_acc', 'rest_time', 'tau_rest', 'mag_norm_th',
                     'mag_dip_th', 'mag_new_time', 'mag_new_gyr', 'tau_mag_ref',
                     'bias_sigma_init', 'bias_sigma_motion', 'gyro_range', 'acc_reject',
                     'acc_reject_time')
PAR = Group('par', "The parameters: AhrsParams's of the same name, and what the wrapper derives",
            [(row.name, row.unit, row.text) for row in AHRS_TABLE
             if row.name in KERNEL_PARAMETERS] + [
    ('use_mag', '1', 'the heading follows the magnetometer (9D)'),
    ('extended', '1', "variant 'extended' (1) or 'plain' (0): the extension term runs"),
    ('has_cal', '1', 'a magnetometer calibration runs (mag_cal and 9D)'),
    ('cal_period', 's', 'learn from a field at most this often'),
    ('motion_bias', '1', 'the bias is learned in motion (tau_bias > 0)'),
    ('velocity_timeout', 's', 'an older velocity is not used'),
])
STATE = Group('ahrs', "One estimate's state", [
    PAR, COEF, EST, REST, GYRO, BIAS, INC, REJ, VEL, HOLE, FIELD, CAL_FEED, CAL])


def table():
    """Markdown rows: every field's path, size, unit and meaning."""
    rows = ['| field | size | unit | meaning |', '|---|---|---|---|']
    for path, unit, meaning, size in STATE.fields():
        rows.append(f'| `{".".join(path)}` | {size} | {unit} | {meaning} |')
    return '\n'.join(rows)


if __name__ == '__main__':
    print(table())
