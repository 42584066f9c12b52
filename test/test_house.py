"""The package's structure: the state groups declared once, read by name."""

import ast
import pathlib

import pytest

from ext_observer.core.ahrs.ahrs_observer import AhrsObserver, AhrsParams
from ext_observer.core.ahrs.ahrs_state import KERNEL_PARAMETERS, STATE
from ext_observer.core.ahrs.record import Group

PACKAGE = pathlib.Path(__file__).resolve().parent.parent / 'ext_observer'
# Flat-state slot names: parameters, coefficients, state, uncertainty, calibration, sizes.
SLOT_PREFIXES = ('P_', 'C_', 'S_', 'U_', 'MC_', 'A_')


def _hand_numbered(folder):
    """Module-level slot constants typed as numbers: ``S_Q = 32``, ``X = Y + 4``."""
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


def test_no_slot_constants_are_left_in_the_core():
    assert _hand_numbered(PACKAGE / 'core') == []


# The names the kernels give a holder (whose [0] is a state record).
HOLDERS = ('state', 'uh', 'holder')


def _state_subscripts(source):
    """
    Where a kernel subscripts a state record (``s[S_Q + 2]``) or a holder at other than ``[0]``.

    A record is a function's argument that the function reads fields of
    (``s.rest.time``); an argument only subscripted is an array or a tuple.
    """
    found = []
    for function in ast.walk(ast.parse(source)):
        if not isinstance(function, ast.FunctionDef):
            continue
        names = {a.arg for a in function.args.args}
        records = {n.value.id for n in ast.walk(function) if isinstance(n, ast.Attribute)
                   and isinstance(n.value, ast.Name) and n.value.id in names}
        for node in ast.walk(function):
            if isinstance(node, ast.Subscript) and isinstance(node.value, ast.Name):
                name = node.value.id
                zero = isinstance(node.slice, ast.Constant) and node.slice.value == 0
                if name in records or (name in HOLDERS and not zero):
                    found.append(f'{node.lineno}: {ast.unparse(node)}')
    return found


# Where the positions of the calibration filter's parts in its vector are
# read: its accessors (offset_of, soft_iron_of, ...), beside the positions.
POSITIONS_READ_IN = 'magcal_layout.py'


def _named_positions(source):
    """
    Where a kernel subscripts an array at a named position (``x[CAL_D + k]``, ``x[CAL_TAU]``).

    A term of the index made of upper-case names (and numbers) alone is a
    position; a row stride times a variable (``p[CAL_N * i + j]``) is not.
    """
    found = []
    for node in ast.walk(ast.parse(source)):
        if not isinstance(node, ast.Subscript):
            continue
        index = node.slice
        terms = []

        def add(e):
            if isinstance(e, ast.BinOp) and isinstance(e.op, (ast.Add, ast.Sub)):
                add(e.left)
                add(e.right)
            elif isinstance(e, ast.UnaryOp):
                add(e.operand)
            elif e is not None:
                terms.append(e)

        for part in ([index.lower, index.upper, index.step] if isinstance(index, ast.Slice)
                     else [index]):
            add(part)
        for term in terms:
            names = [n.id for n in ast.walk(term) if isinstance(n, ast.Name)]
            if names and all(n.isupper() for n in names):
                found.append((node.lineno, node.col_offset, ast.unparse(node)))
                break
    return [f'{line}: {text}' for line, _, text in sorted(found)]


def test_no_kernel_reads_or_writes_the_state_by_an_index():
    from ext_observer.core.ahrs import compiled
    found = {}
    for name, path in zip(compiled.KERNEL_SOURCES, compiled.kernel_paths()):
        source = pathlib.Path(path).read_text(encoding='utf-8')
        hits = _state_subscripts(source)
        if name != POSITIONS_READ_IN:
            hits += _named_positions(source)
        if hits:
            found[name] = hits
    assert found == {}, found
    # The check sees what it looks for.
    assert _state_subscripts('def f(s, state):\n    s[S_LP + 3] = state[1] + s.est.q[0]\n') == [
        '2: s[S_LP + 3]', '2: state[1]']
    assert _state_subscripts('def f(s, at):\n    return s[at + 1]\n') == []  # an array
    assert _state_subscripts('def f(state):\n    s = state[0]\n    s.inc.lp[3] = 1.0\n') == []
    assert _named_positions(
        'def f(cal, p, i, j, k):\n    x = cal.x\n    d = x[CAL_D + k] + x[CAL_TAU] + x[-CAL_Z]\n'
        '    p[(CAL_N + 1) * CAL_TAU] = p[CAL_N * i + j] + x[3] + x[CAL_S:CAL_S + 3][0]\n') == [
        '3: x[CAL_D + k]', '3: x[CAL_TAU]', '3: x[-CAL_Z]', '4: p[(CAL_N + 1) * CAL_TAU]',
        '4: x[CAL_S:CAL_S + 3]']


def test_the_estimators_state_is_its_groups_each_declared_once_every_field_with_its_meaning():
    groups = []

    def walk(group):
        for member in group.members:
            if isinstance(member, Group):
                groups.append(member.name)
                walk(member)

    walk(STATE)
    # Each group's name is unique in the state, and it is declared once in the
    # package (beside the code that owns it: ahrs_state.py holds the rest).
    assert len(groups) == len(set(groups)), groups
    declared = {}
    for path in sorted((PACKAGE / 'core').rglob('*.py')):
        for node in ast.parse(path.read_text(encoding='utf-8')).body:
            if (isinstance(node, ast.Assign) and isinstance(node.value, ast.Call)
                    and isinstance(node.value.func, ast.Name) and node.value.func.id == 'Group'):
                declared.setdefault(node.value.args[0].value, []).append(path.name)
    assert all(len(declared.get(name, [])) == 1 for name in groups), declared
    # Every field has its meaning (docs/layout.md's table) and a unit ('' where none).
    fields = STATE.fields()
    for path, unit, meaning, size in fields:
        assert isinstance(unit, str) and meaning.strip() and size >= 1, path
    # Contiguous: each field starts where the one before ends; the record is its fields.
    at = 0
    for path, _, _, size in fields:
        assert STATE.offset('.'.join(path)) == at, path
        at += size
    assert STATE.size == at
    # The estimator's parameters are the first fields, in AhrsParams's names.
    first = fields[:len(KERNEL_PARAMETERS)]
    assert tuple(path for path, *_ in first) == tuple(('par', n) for n in KERNEL_PARAMETERS)
    assert set(KERNEL_PARAMETERS) <= set(AhrsParams.DEFAULTS)
    assert STATE.offset('par.alpha') == 0


def test_the_estimators_fields_are_read_by_name():
    est = AhrsObserver(compiled=False)
    est.update((0.1, 0.0, -0.02), (0.3, 0.1, 9.8), None, 0.01)
    assert est.field('q') == est.q and est.field('est.q') == est.q
    assert est.field('bias.rate') == est.bias
    assert len(est.field('inc.lp')) == 6 and isinstance(est.field('k_acc'), float)
    est.set_field('mag_used', 3.0)
    assert est.field('mag_used') == 3.0 and est.field('field.mag_used') == 3.0
    est.set_field('bias.rate', (0.01, -0.02, 0.03))
    assert est.bias == (0.01, -0.02, 0.03)
    # A vector takes its size of values, no fewer, no more, not one.
    for wrong in (1.0, (1.0, 0.0, 0.0), (1.0, 0.0, 0.0, 0.0, 0.0)):
        with pytest.raises(ValueError, match='values'):
            est.set_field('q', wrong)
    batch = AhrsObserver(batch=3, compiled=False)
    batch.set_field('mag_used', [1.0, 2.0, 3.0])
    assert list(batch.field('mag_used')) == [1.0, 2.0, 3.0]


def _raw_imu_rows():
    from ext_observer.core.ahrs.ahrs_params import AHRS_TABLE
    from ext_observer.core.ahrs.ahrs_params import UNCERTAINTY_TABLE
    from ext_observer.pipeline.imu_filter_parameters import AHRS_PREFIX, COVARIANCE_PREFIX
    return ([(AHRS_PREFIX, row) for row in AHRS_TABLE]
            + [(COVARIANCE_PREFIX, row) for row in UNCERTAINTY_TABLE])


def test_every_raw_imu_parameter_comes_from_the_one_table():
    from ext_observer.core.ahrs.ahrs_params import AhrsParams
    from ext_observer.core.ahrs.ahrs_params import UncertaintyParams
    from ext_observer.nodes.ros_parameters import descriptor
    from ext_observer.pipeline.imu_filter_parameters import (IMU_FILTER_PARAMETERS,
                                                             imu_filter_settings)
    from docgen.parameter_tables import markdown_table

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


# --- imports: downward only, public names only ----------------------------------------------

ROOT = PACKAGE.parent


def _modules():
    """``{dotted name: path}`` of every module of ext_observer, bench and docgen."""
    found = {}
    for base in ('ext_observer', 'bench', 'docgen'):
        for path in (ROOT / base).rglob('*.py'):
            parts = list(path.relative_to(ROOT).with_suffix('').parts)
            if parts[-1] == '__init__':
                parts = parts[:-1]
            found['.'.join(parts)] = path
    return found


def _imports(modules):
    """Every import between the modules (function-level ones too): ``(edges, private names)``."""
    edges = {name: set() for name in modules}
    private = []
    for name, path in modules.items():
        package = name.split('.') if path.name == '__init__.py' else name.split('.')[:-1]
        for node in ast.walk(ast.parse(path.read_text(encoding='utf-8'))):
            if isinstance(node, ast.Import):
                edges[name].update(a.name for a in node.names if a.name in modules)
            elif isinstance(node, ast.ImportFrom):
                if node.level:
                    target = '.'.join(package[:len(package) - node.level + 1]
                                      + ([node.module] if node.module else []))
                else:
                    target = node.module
                for alias in node.names:
                    if f'{target}.{alias.name}' in modules:
                        edges[name].add(f'{target}.{alias.name}')
                    elif target in modules:
                        edges[name].add(target)
                        if alias.name.startswith('_') and not alias.name.startswith('__'):
                            private.append(f'{name} imports {target}.{alias.name}')
    return edges, private


def _cycles(edges):
    """The strongly connected components of more than one module (Tarjan, iterative)."""
    index, low, stack, on_stack, found = {}, {}, [], set(), []
    for root in edges:
        if root in index:
            continue
        work = [(root, iter(sorted(edges[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            node, children = work[-1]
            child = next(children, None)
            if child is not None:
                if child not in index:
                    index[child] = low[child] = len(index)
                    stack.append(child)
                    on_stack.add(child)
                    work.append((child, iter(sorted(edges[child]))))
                elif child in on_stack:
                    low[node] = min(low[node], index[child])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[node])
            if low[node] == index[node]:
                component = []
                while True:
                    member = stack.pop()
                    on_stack.discard(member)
                    component.append(member)
                    if member == node:
                        break
                if len(component) > 1:
                    found.append(sorted(component))
    return found


def test_no_import_cycle_and_no_private_name_across_modules():
    edges, private = _imports(_modules())
    assert 'ext_observer.core.ahrs.compiled' in edges['ext_observer.core.ahrs.ahrs_observer']
    assert _cycles(edges) == []
    assert private == []
    # The check finds a cycle where there is one.
    assert _cycles({'a': {'b'}, 'b': {'c'}, 'c': {'a'}, 'd': {'a'}}) == [['a', 'b', 'c']]


def test_the_package_imports_neither_the_docs_writers_nor_the_benchmarks():
    # Neither is installed: the package finds docgen through source_tree only.
    edges, _ = _imports(_modules())
    found = [f'{name} imports {target}' for name, targets in edges.items()
             if name.startswith('ext_observer') for target in targets
             if target.split('.')[0] in ('docgen', 'bench')]
    assert found == []


def test_the_core_manages_no_processes_and_imports_no_ros():
    for path in sorted((PACKAGE / 'core').rglob('*.py')):
        for node in ast.walk(ast.parse(path.read_text(encoding='utf-8'))):
            names = ([a.name for a in node.names] if isinstance(node, ast.Import)
                     else [node.module or ''] if isinstance(node, ast.ImportFrom) else [])
            for name in names:
                top = name.split('.')[0]
                assert top not in ('subprocess', 'multiprocessing', 'fcntl', 'signal',
                                   'threading', 'rclpy'), (
                    f'{path.relative_to(PACKAGE)} imports {name}')
                assert not top.endswith(('_msgs', '_srvs')), path
                assert not name.startswith(('ext_observer.pipeline', 'ext_observer.nodes',
                                            'ext_observer.recordings')), path


# --- the offline path without ROS ----------------------------------------------------------

_NO_ROS = '''
import sys


class NoRos:
    """Refuse rclpy and every message package, as on a machine without ROS."""

    def find_spec(self, name, path=None, target=None):
        top = name.split('.')[0]
        if (top in ('rclpy', 'builtin_interfaces', 'rcl_interfaces')
                or top.endswith(('_msgs', '_srvs'))):
            raise ImportError(f'no ROS here: {name}')
        return None


sys.meta_path.insert(0, NoRos())
'''

_OFFLINE = '''
import os
import numpy as np

try:
    import rclpy  # noqa: F401
except ImportError:
    pass
else:
    raise SystemExit('the blocker let rclpy in')

import ext_observer.core as core
from ext_observer import attitude_from_imu
from ext_observer.__main__ import main

assert abs(core.certified_alpha_max() - 0.0762) < 1e-3
data = np.load(os.path.join({data!r}, 'broad_01_undisturbed_slow_rotation_A.npz'))
names = list(data)
rate = float(data['rate']) if 'rate' in names else None
run = attitude_from_imu(data['gyr'][:600], data['acc'][:600], data['mag'][:600] * 1e-6,
                        rate=rate)
assert run.quaternions.shape == (600, 4) and np.all(np.isfinite(run.quaternions))
out = {out!r}
assert main(['example-data', '--out', out, '--seconds', '3', '--storage', 'mcap']) in (0, None)
folder = sorted(os.listdir(out))
csv = [f for f in folder if f.endswith('.csv')][0]
bag = [f for f in folder if f.endswith('_mcap')][0]
assert main(['csv', os.path.join(out, csv), '--out', os.path.join(out, 'ours.csv')]) in (0, None)
assert main(['bag', os.path.join(out, bag), '--out', os.path.join(out, 'ours')]) in (0, None)
leaked = sorted(m for m in sys.modules if m.split('.')[0] == 'rclpy' or m.endswith('_msgs'))
assert not leaked, leaked
print('offline path ran without ROS')
'''


def test_the_offline_path_runs_without_ros(tmp_path):
    import subprocess
    import sys
    code = _NO_ROS + _OFFLINE.format(data=str(ROOT / 'test' / 'data'), out=str(tmp_path / 'ex'))
    env = dict(__import__('os').environ, EXT_OBSERVER_COMPILED='0')
    done = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True,
                          env=env, timeout=300, cwd=str(tmp_path))
    assert done.returncode == 0, done.stdout + done.stderr
    assert 'offline path ran without ROS' in done.stdout


def test_the_tree_shows_the_architecture():
    # At most 8 modules at the top; each subpackage says what lives there.
    assert len(list(PACKAGE.glob('*.py'))) <= 8
    for init in PACKAGE.rglob('__init__.py'):
        text = ast.get_docstring(ast.parse(init.read_text(encoding='utf-8')))
        assert text and len(text.splitlines()) <= 40, init.relative_to(ROOT)
    layout = (ROOT / 'docs' / 'layout.md').read_text(encoding='utf-8')
    for folder in ('core/', 'ahrs/', 'paper/', 'pipeline/', 'nodes/', 'recordings/', 'broad/'):
        assert folder in layout, folder
