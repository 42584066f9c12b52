"""The package's structure (issue 28): layouts declared once."""

import ast
import pathlib

import pytest

from ext_observer.core.ahrs import ahrs_kernel, magcal_layout, uncertainty_kernel
from ext_observer.core.ahrs.estimator import AhrsObserver
from ext_observer.core.ahrs.layout import Layout

PACKAGE = pathlib.Path(__file__).resolve().parent.parent / 'ext_observer'
# Flat-state slot names: parameters, coefficients, state, uncertainty, calibration, sizes.
SLOT_PREFIXES = ('P_', 'C_', 'S_', 'U_', 'MC_', 'A_')


def _hand_numbered(folder):
    """Module-level slot constants whose value is typed as a number: ``S_Q = 32``, ``X = Y + 4``."""
    found = []
    for path in sorted(folder.rglob('*.py')):
        for node in ast.parse(path.read_text(encoding='utf-8')).body:
            if not (isinstance(node, ast.Assign) and len(node.targets) == 1
                    and isinstance(node.targets[0], ast.Name)):
                continue
            name = node.targets[0].id.lstrip('_')
            if not name.startswith(SLOT_PREFIXES) and not name.endswith('_SIZE'):
                continue
            walked = list(ast.walk(node.value))
            if any(isinstance(n, ast.Call) for n in walked):
                continue
            if any(isinstance(n, ast.Constant) and type(n.value) is int for n in walked):
                found.append(f'{path.relative_to(PACKAGE)}:{node.lineno} {ast.unparse(node)}')
    return found


def test_the_kernels_slots_come_from_their_layout_tables():
    found = _hand_numbered(PACKAGE / 'core')
    assert len(found) <= 10, '\n'.join(found)
    for module, layout, size in ((ahrs_kernel, ahrs_kernel.AHRS, ahrs_kernel.A_SIZE),
                                 (magcal_layout, magcal_layout.MAGCAL, magcal_layout.MC_SIZE),
                                 (uncertainty_kernel, uncertainty_kernel.UNCERTAINTY,
                                  uncertainty_kernel.U_SIZE)):
        spans = sorted(layout.fields.values())
        assert spans[0][0] == 0 and layout.size == size
        # Contiguous: each field starts where the one before ends.
        assert all(a + n == b for (a, n), (b, _) in zip(spans, spans[1:]))
        assert spans[-1][0] + spans[-1][1] == size
        # Every slot constant of the module is the offset of a field (or the size).
        offsets = {offset for offset, _ in spans} | {size}
        tree = ast.parse(pathlib.Path(module.__file__).read_text(encoding='utf-8'))
        assigned = {t.id for node in tree.body if isinstance(node, ast.Assign)
                    for t in node.targets if isinstance(t, ast.Name)}
        for name in assigned:
            if name.startswith(SLOT_PREFIXES) and name != 'MC0':
                assert getattr(module, name) in offsets, name
    # The estimator's parameters are the first slots, in AhrsParams's names.
    assert ahrs_kernel.PARAMETERS == tuple(ahrs_kernel.AHRS.parameters)
    assert ahrs_kernel.AHRS.offset('alpha') == ahrs_kernel.P_ALPHA


def test_a_layout_refuses_a_field_declared_twice_or_empty():
    layout = Layout()
    assert layout.field('q', 4) == 0 and layout.field('bias', 3) == 4 and layout.size == 7
    with pytest.raises(ValueError, match='twice'):
        layout.field('q')
    with pytest.raises(ValueError, match='at least 1'):
        layout.field('none', 0)


def test_the_estimators_fields_are_read_by_name():
    est = AhrsObserver(compiled=False)
    est.update((0.1, 0.0, -0.02), (0.3, 0.1, 9.8), None, 0.01)
    assert est.field('q') == est.q and est.field('bias') == est.bias
    assert len(est.field('lp')) == 6 and isinstance(est.field('k_acc'), float)
    est.set_field('mag_used', 3.0)
    assert est.field('mag_used') == 3.0
    with pytest.raises(ValueError, match='slots'):
        est.set_field('q', 1.0)
    batch = AhrsObserver(batch=3, compiled=False)
    batch.set_field('mag_used', [1.0, 2.0, 3.0])
    assert list(batch.field('mag_used')) == [1.0, 2.0, 3.0]


def _raw_imu_rows():
    from ext_observer.core.ahrs.ahrs_params import AHRS_TABLE
    from ext_observer.core.ahrs.uncertainty import UNCERTAINTY_TABLE
    from ext_observer.pipeline.raw_imu import AHRS_PREFIX, COVARIANCE_PREFIX
    return ([(AHRS_PREFIX, row) for row in AHRS_TABLE]
            + [(COVARIANCE_PREFIX, row) for row in UNCERTAINTY_TABLE])


def test_every_raw_imu_parameter_comes_from_the_one_table():
    from ext_observer.core.ahrs.ahrs_params import AhrsParams
    from ext_observer.core.ahrs.uncertainty import UncertaintyParams
    from ext_observer.nodes.parameters import descriptor
    from ext_observer.pipeline.imu_filter_parameters import (IMU_FILTER_PARAMETERS,
                                                             imu_filter_settings)
    from ext_observer.pipeline.parameter_specs import markdown_table

    specs = {spec.name: spec for spec in IMU_FILTER_PARAMETERS}
    rows = _raw_imu_rows()
    # Every prefixed parameter of the node is a row, and every row a parameter.
    assert {prefix + row.name for prefix, row in rows} == {
        name for name in specs if name.startswith(('ahrs.', 'covariance.'))}
    docs = (PACKAGE.parent / 'docs' / 'parameters.md').read_text(encoding='utf-8')
    yaml = (PACKAGE.parent / 'config' / 'imu_filter.yaml').read_text(encoding='utf-8')
    defaults = {**{f'ahrs.{k}': v for k, v in AhrsParams.DEFAULTS.items()},
                **{f'covariance.{k}': v for k, v in UncertaintyParams.DEFAULTS.items()}}
    values = {spec.name: spec.default for spec in IMU_FILTER_PARAMETERS}
    for prefix, row in rows:
        spec = specs[prefix + row.name]
        # The core's default, the node's default, the docs' and the YAML's.
        assert defaults[spec.name] == row.default == spec.default
        assert row.description in spec.description and spec.constraints == row.rule
        assert markdown_table([spec]).splitlines()[-1] in docs.splitlines(), spec.name
        assert f'    {spec.name}: {spec.default_text}' in yaml.splitlines(), spec.name
        # The node's declared range is the row's.
        declared = descriptor(spec)
        if row.flag:
            assert spec.range is None and not declared.floating_point_range
            continue
        (declared_range,) = declared.floating_point_range
        assert (declared_range.from_value, declared_range.to_value) == (row.low, row.high)
        # And the node's validation enforces the row's ends, open or closed.
        for value, accepted in ((row.low, row.low_closed), (row.high, not row.high_open)):
            candidate = dict(values, **{spec.name: value})
            if accepted:
                imu_filter_settings(candidate)
            else:
                with pytest.raises(ValueError, match=row.name):
                    imu_filter_settings(candidate)


def test_the_node_refuses_what_the_core_refuses():
    from ext_observer.pipeline.imu_filter_parameters import (IMU_FILTER_PARAMETERS,
                                                             imu_filter_settings)
    values = {spec.name: spec.default for spec in IMU_FILTER_PARAMETERS}
    # alpha's rclpy range is [0, 0.0762]; the certified range is open at 0.0762.
    with pytest.raises(ValueError, match='alpha must be below 0.0762'):
        imu_filter_settings(dict(values, **{'ahrs.alpha': 0.0762}))
    imu_filter_settings(dict(values, **{'ahrs.alpha': 0.0761}))
