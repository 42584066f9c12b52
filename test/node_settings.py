"""``imu_filter_node``'s settings for keyword changes, the others at their defaults."""

from ext_observer.pipeline.imu_filter_parameters import IMU_FILTER_PARAMETERS, imu_filter_settings


def node_settings(**changes):
    """The settings the node makes of its rows with ``changes`` (names as in its YAML)."""
    values = {spec.name: spec.default for spec in IMU_FILTER_PARAMETERS}
    values.update(changes)
    return imu_filter_settings(values)
