"""
Physical constants, each defined once (a test fails on a second definition).

``STANDARD_GRAVITY``: the standard acceleration of gravity, m/s² (ISO 80000-3),
what the accelerometer's specific force is compared with and what
``imu/data``'s gravity-free acceleration removes.
"""

__all__ = ['STANDARD_GRAVITY']

STANDARD_GRAVITY = 9.80665  # m/s²
