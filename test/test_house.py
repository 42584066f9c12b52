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
