"""
The colcon path, for real: build in a temporary workspace, source
``install/setup.bash``, find the package the way ``ros2 run`` does, and run
the installed ``observer_node`` with the installed params file.
"""

import os
import shutil
import subprocess
import sys
import time

import pytest

from conftest import REPO

IGNORED = shutil.ignore_patterns('.venv', '.git', 'build', 'install', 'log', 'out',
                                 '*.egg-info', '__pycache__', '.pytest_cache',
                                 '.hypothesis')


def sourced_environment(workspace, env):
    """Return the environment after ``source install/setup.bash``."""
    result = subprocess.run(
        ['bash', '-c', 'source install/setup.bash && env -0'], cwd=workspace, env=env,
        capture_output=True, timeout=60, check=True)
    pairs = (item.split('=', 1) for item in result.stdout.decode().split('\0') if item)
    return dict(pair for pair in pairs if len(pair) == 2)


@pytest.fixture(scope='module')
def workspace(tmp_path_factory):
    """Build ext_observer with colcon in a fresh workspace; return its root."""
    bin_dir = os.path.dirname(sys.executable)
    colcon = os.path.join(bin_dir, 'colcon')
    if not os.path.exists(colcon):
        pytest.fail(f'colcon is not installed next to {sys.executable}; run `make test`')
    root = tmp_path_factory.mktemp('colcon_ws')
    shutil.copytree(REPO, root / 'src' / 'ext_observer', ignore=IGNORED)
    env = {key: value for key, value in os.environ.items()
           if key not in ('AMENT_PREFIX_PATH', 'COLCON_PREFIX_PATH', 'PYTHONPATH')}
    env['PATH'] = bin_dir + os.pathsep + env.get('PATH', '')
    result = subprocess.run([colcon, 'build', '--base-paths', 'src'], cwd=root, env=env,
                            capture_output=True, timeout=300)
    assert result.returncode == 0, result.stdout.decode() + result.stderr.decode()
    return root, env


def test_colcon_installs_the_ros_layout(workspace):
    root, _ = workspace
    prefix = root / 'install' / 'ext_observer'
    for name in ('gyro_node', 'observer_node', 'monitor_node', 'imu_filter_node'):
        assert os.access(prefix / 'lib' / 'ext_observer' / name, os.X_OK), name
    share = prefix / 'share'
    assert (share / 'ament_index' / 'resource_index' / 'packages' / 'ext_observer').exists()
    assert (share / 'ext_observer' / 'package.xml').exists()
    assert (share / 'ext_observer' / 'config' / 'ext_observer.yaml').exists()
    assert (share / 'ext_observer' / 'config' / 'imu_filter.yaml').exists()
    assert (share / 'ext_observer' / 'launch' / 'imu_filter.launch.py').exists()
    # What writes the clone's docs, and the benchmarks, are not installed.
    packages = {path.name for path in (prefix / 'lib').glob('python*/site-packages/*')}
    assert 'ext_observer' in packages
    assert not packages & {'docgen', 'bench', 'test'}, packages


def test_the_installed_package_says_it_cannot_write_the_docs(workspace):
    root, env = workspace
    sourced = sourced_environment(root, env)
    # A folder without docgen/: only the installed copy is found.
    result = subprocess.run([sys.executable, '-m', 'ext_observer', 'docs'], cwd=root / 'install',
                            env=sourced, capture_output=True, text=True, timeout=60)
    assert result.returncode == 2, result.stdout + result.stderr
    assert 'docgen/' in result.stderr and 'Traceback' not in result.stderr


def test_ros2_run_path_with_the_installed_params_file(workspace, ros_processes):
    root, env = workspace
    sourced = sourced_environment(root, env)
    # What `ros2 run ext_observer observer_node` resolves.
    result = subprocess.run(
        [sys.executable, '-c',
         'from ament_index_python.packages import get_package_prefix, '
         'get_package_share_directory\n'
         'import ext_observer\n'
         "print(get_package_prefix('ext_observer'))\n"
         "print(get_package_share_directory('ext_observer'))\n"
         'print(ext_observer.__file__)'],
        cwd=root, env=sourced, capture_output=True, timeout=60)
    assert result.returncode == 0, result.stderr.decode()
    prefix, share, module = result.stdout.decode().split()
    assert prefix == str(root / 'install' / 'ext_observer')
    # The colcon-installed copy is what runs, not the source tree.
    assert module.startswith(prefix)
    for name, config, started in (
            ('observer_node', 'ext_observer.yaml', 'extended observer, alpha 0.01'),
            ('imu_filter_node', 'imu_filter.yaml', 'raw IMU on /imu/data_raw and /imu/mag')):
        executable = os.path.join(prefix, 'lib', 'ext_observer', name)
        params = os.path.join(share, 'config', config)
        process = ros_processes([executable, '--ros-args', '--params-file', params],
                                env=sourced)
        deadline = time.monotonic() + 30.0
        while started not in process.output:
            assert process.process.poll() is None, process.output
            if time.monotonic() > deadline:
                pytest.fail(f'{name} did not start:\n{process.output}')
            time.sleep(0.1)
        assert process.interrupt(timeout=10.0) == 0, process.output
        assert 'Traceback' not in process.output
        # The installed params file gives nothing imu_filter_madgwick-only.
        assert 'not used here' not in process.output
