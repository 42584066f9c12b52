"""
Asserts of the test files that the suite never runs (issue 31): from a coverage run of the tests.

``coverage run --branch --include='test/*' -m pytest test bench/test_*.py``
then ``coverage json -o out/test_coverage.json`` then
``python mutation/asserts_never_run.py out/test_coverage.json``: prints each
line of a test file (``test/test_*.py``) that never ran and is an assert or
holds one under it (a loop or branch whose body never ran: a branch never
taken leaves its first line unrun). The helpers' error paths (a
``pytest.fail`` in a fixture, a timeout's message) are not asserts and are
not listed. Exits 1 when it lists anything.
"""

import ast
import json
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)


def assert_lines(path):
    """The lines of ``path`` that are an assert or a compound statement with an assert in it."""
    with open(path, encoding='utf-8') as f:
        tree = ast.parse(f.read())
    lines = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.Assert):
            lines[node.lineno] = 'assert'
        elif isinstance(node, (ast.If, ast.For, ast.While, ast.With, ast.Try)):
            if any(isinstance(n, ast.Assert) for n in ast.walk(node)):
                lines.setdefault(node.lineno, type(node).__name__.lower())
        elif isinstance(node, ast.Call):
            name = getattr(node.func, 'attr', getattr(node.func, 'id', ''))
            if name.startswith('assert_') or name == 'raises':
                lines.setdefault(node.lineno, name)
    return lines


def main(argv=None):
    argv = sys.argv[1:] if argv is None else argv
    with open(argv[0], encoding='utf-8') as f:
        report = json.load(f)
    found = []
    for name, data in sorted(report['files'].items()):
        base = os.path.basename(name)
        if not (base.startswith('test_') and base.endswith('.py')):
            continue
        path = name if os.path.isabs(name) else os.path.join(REPO, name)
        asserts = assert_lines(path)
        for line in data.get('missing_lines', []):
            if line in asserts:
                found.append(f'{name}:{line}: never runs ({asserts[line]})')
    for line in found:
        print(line)
    print(f'{len(found)} found')
    return 1 if found else 0


if __name__ == '__main__':
    sys.exit(main())
