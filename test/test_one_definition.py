"""
One definition of each idea: a second one, anywhere in the sources, fails here.

Standard gravity (``ext_observer/core/constants.py``), the kernels'
quaternion product (``ahrs_filters.quat_multiply``) and a specific force's
deviation from gravity (``ahrs_filters.gravity_deviation``) are written
once; the other files import them. The split of the BROAD trials:
test/broad/test_split.py. The sources: the package, bench/ and docgen/.
"""

import os
import re

from conftest import REPO

SOURCES = ('ext_observer', 'bench', 'docgen')
# A Hamilton product's scalar part written out: a·b − a·b − a·b − a·b.
_TERM = r'(\w+(?:\[\d\])?) \* (\w+(?:\[\d\])?)'
_PRODUCT_PATTERN = re.compile(' - '.join([_TERM] * 4))


class _Product:
    """A written-out product of two quaternions (a squared norm's terms are no product)."""

    @staticmethod
    def search(line):
        return any(any(a != b for a, b in zip(m.groups()[::2], m.groups()[1::2]))
                   for m in _PRODUCT_PATTERN.finditer(line))


_PRODUCT = _Product()
_DEVIATION = re.compile(r'max\(\w+ \* \w+, 0\.5 \* \(')


def python_files():
    for top in SOURCES:
        for folder, _, names in os.walk(os.path.join(REPO, top)):
            for name in names:
                if name.endswith('.py'):
                    path = os.path.join(folder, name)
                    with open(path, encoding='utf-8') as f:
                        yield os.path.relpath(path, REPO), f.read()


def test_standard_gravity_is_defined_once():
    found = [(path, n) for path, text in python_files()
             for n, line in enumerate(text.splitlines(), 1)
             if '9.80665' in line and not line.lstrip().startswith('#')]
    assert found == [('ext_observer/core/constants.py', 11)], found


def test_the_kernels_quaternion_product_is_written_once():
    found = [(path, n) for path, text in python_files()
             if path.startswith('ext_observer/core/ahrs/')
             for n, line in enumerate(text.splitlines(), 1) if _PRODUCT.search(line)]
    assert [path for path, _ in found] == ['ext_observer/core/ahrs/ahrs_filters.py'], found


def test_the_deviation_from_gravity_is_written_once():
    # max(d_z², (d_x² + d_y²) / 2) / g²: ahrs_filters.gravity_deviation.
    found = [(path, n) for path, text in python_files()
             for n, line in enumerate(text.splitlines(), 1) if _DEVIATION.search(line)]
    assert [path for path, _ in found] == ['ext_observer/core/ahrs/ahrs_filters.py'], found


def test_the_checks_find_a_second_definition():
    # The patterns match what they look for (else the tests above pass on nothing).
    assert _PRODUCT.search('pw = w * c - x * ex - y * ey - z * ez')
    assert _PRODUCT.search('q[0] = a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3]')
    assert not _PRODUCT.search('n2 = w * w + x * x + y * y + z * z')
    assert not _PRODUCT.search('s = (w * w - x * x - y * y - z * z)')
    assert _DEVIATION.search('e = max(dz * dz, 0.5 * (vx * vx + vy * vy)) / (G * G)')
