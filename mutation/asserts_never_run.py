"""
Asserts of the test files that the suite never runs: from a coverage run of the tests.

``coverage run --branch --include='test/*' -m pytest test``
then ``coverage json -o out/test_coverage.json`` then
``python mutation/asserts_never_run.py out/test_coverage.json``: prints each
line of a test file (``test/test_*.py``) that never ran and is an assert or
holds one under it (a loop or branch whose body never ran: a branch never
taken leaves its first line unrun). The helpers' error paths (a
``pytest.fail`` in a fixture, a timeout's message) are not asserts and are
not listed, nor the functions the run never entered (a test deselected or
skipped as a whole: the soak, the two-host bed) or that ended in a skip
(``importorskip`` of a package PyPI does not have). The test files must be as
they were during the run. Exits 1 when it lists anything.
"""

import ast
import json
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)


def assert_lines(path):
    """
    ``{line: what}`` of ``path``'s asserts and of the statements with one in them, per function.

    Returns ``[(body_lines, {line: what}, skip_lines)]``, one per function
    (the lines of its own body, nested functions apart), so that a function the run never
    entered (a test deselected or skipped on purpose: the soak, the two-host
    bed) can be told from a loop or branch that did not run inside one that did.
    """
    with open(path, encoding='utf-8') as f:
        tree = ast.parse(f.read())
    functions = []
    for function in ast.walk(tree):
        if not isinstance(function, (ast.FunctionDef, ast.AsyncFunctionDef)):
            continue
        body, lines, skips = set(), {}, set()
        stack = list(function.body)
        while stack:
            node = stack.pop()
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)):
                continue
            if isinstance(node, ast.stmt):
                body.add(node.lineno)
            if isinstance(node, ast.Assert):
                lines[node.lineno] = 'assert'
            elif isinstance(node, (ast.If, ast.For, ast.While, ast.With, ast.Try)):
                if any(isinstance(n, ast.Assert) for n in ast.walk(node)):
                    lines.setdefault(node.lineno, type(node).__name__.lower())
            elif isinstance(node, ast.Call):
                name = getattr(node.func, 'attr', getattr(node.func, 'id', ''))
                if name.startswith('assert_') or name == 'raises':
                    lines.setdefault(node.lineno, name)
                elif name in ('skip', 'importorskip'):
                    skips.add(node.lineno)
            stack.extend(ast.iter_child_nodes(node))
        functions.append((body, lines, skips))
    return functions


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
        executed = set(data.get('executed_lines', []))
        missing = set(data.get('missing_lines', []))
        for body, asserts, skips in assert_lines(path):
            if not body & executed:
                continue  # never entered: deselected or skipped as a whole
            if max(body & executed) in skips:
                continue  # skipped where it stands (pytest.skip, importorskip)
            for line in sorted(missing & set(asserts)):
                found.append(f'{name}:{line}: never runs ({asserts[line]})')
    for line in found:
        print(line)
    print(f'{len(found)} found')
    return 1 if found else 0


if __name__ == '__main__':
    sys.exit(main())
