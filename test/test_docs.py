"""
The documentation stays true to the code.

- The parameter tables of ``docs/parameters.md`` equal what
  ``python -m ext_observer docs`` generates from the nodes' parameter specs.
- Every diagnostics key, drop reason, reset cause and guard reason the nodes
  publish is on ``docs/diagnostics.md``, and every observer drop reason has a
  row in the fault table of ``docs/faults.md``.
- Every test a page cites (``test_x.py::test_name``) exists.
- Every relative link in ``README.md`` and ``docs/*.md`` resolves to a file
  and, with a ``#anchor`` into a Markdown file, to one of its headings, by
  GitHub's anchor rules.
- Every page of ``docs/`` is in the index ``docs/README.md`` and opens with
  a sentence; the README stays short.
- No page holds a path of the machine that wrote it (a generated page's
  data folder or temporary file): paths are relative to the repository.
- The package, its tests and its docs name a goal or a fault by what it is,
  never by the number of an issue of this project; another project's issue
  is cited with that project's name (``imu_tools #3``).
"""

import fnmatch
import glob
import os
import re
import unicodedata

import pytest

from conftest import REPO

DOCS = os.path.join(REPO, 'docs')
README = os.path.join(REPO, 'README.md')
README_MAX_LINES = 150
# Absolute paths that only one machine has: home folders, temporary
# folders, this checkout's own. (/opt/ros/jazzy, where ROS installs, is everyone's.)
MACHINE_PATH = re.compile(
    r'(?<![\w.~-])(/(?:work|tmp|root|home|Users|var/folders|private|mnt)/'
    + '|' + re.escape(os.path.dirname(REPO)) + '/|' + re.escape(REPO) + r'\b)')


# An issue of this project by number: the word (or its plural) then digits, or a
# hash then digits after a space or an opening parenthesis.
ISSUE_NUMBER = re.compile(r'\bissues?\s*#?\s*\d+\b|(?:(?<=\s)|(?<=\())#\d+(?![\w-])', re.I)
# What may stand before one: another project, named (`CCNYRoboticsLab/imu_tools #195`,
# `dlaidig/vqf #25`, `imu_tools #3`, or the word issue after the project's name).
OTHER_PROJECT = re.compile(r'(?:[\w.-]+/[\w.-]+|\bimu_tools|\bvqf|\bFusion|\bimu_filter_madgwick'
                           r'|\brobot_localization|\brclpy|\bnumba|\bnumpy)`?\s*$', re.I)
def issue_numbers(text):
    """Return (line, mention) of each issue by number not led by another project's name."""
    return [(text[:m.start()].count('\n') + 1, m.group())
            for m in ISSUE_NUMBER.finditer(text)
            if not OTHER_PROJECT.search(text[text.rfind('\n', 0, m.start()) + 1:m.start()])]


def _read(path):
    with open(path, encoding='utf-8') as file:
        return file.read()


def _pages():
    """Return README.md and every docs/*.md, as absolute paths."""
    return [README] + sorted(glob.glob(os.path.join(DOCS, '*.md')))


def _name(path):
    return os.path.relpath(path, REPO)


# Markdown, as far as links and headings need it -----------------------------

FENCE = re.compile(r'^ {0,3}(```|~~~)')
INLINE_CODE = re.compile(r'(`+)(.+?)\1')
LINK = re.compile(r'!?\[(?:[^\[\]]|\[[^\[\]]*\])*\]\(\s*<?([^)\s>]*)>?(?:\s+"[^"]*")?\s*\)')
REFERENCE = re.compile(r'^ {0,3}\[[^\]]+\]:\s*<?(\S+?)>?(?:\s+.*)?$')
HTML_LINK = re.compile(r'\b(?:href|src)="([^"]+)"')
HTML_ANCHOR = re.compile(r'<a\s+(?:name|id)="([^"]+)"')
ATX = re.compile(r'^ {0,3}(#{1,6})\s+(.*?)\s*#*\s*$')
SETEXT = re.compile(r'^ {0,3}(=+|-+)\s*$')


def _prose_lines(text):
    """Yield the lines outside fenced code blocks, as (number, line)."""
    fence = None
    for number, line in enumerate(text.splitlines(), 1):
        match = FENCE.match(line)
        if fence is None and match:
            fence = match.group(1)
        elif fence is not None and line.strip().startswith(fence):
            fence = None
        elif fence is None:
            yield number, line


def slug(heading):
    """
    Return GitHub's anchor of a heading.

    The text as rendered (inline code, links and emphasis reduced to their
    text), lowercased, every character but letters, marks, digits, ``_``,
    ``-`` and spaces removed, spaces turned into ``-``.
    """
    text = re.sub(r'!?\[([^\]]*)\]\([^)]*\)', r'\1', heading)
    text = INLINE_CODE.sub(lambda match: match.group(2), text)
    text = re.sub(r'<[^>]+>', '', text).lower()
    kept = [c for c in text
            if c in ' -_' or unicodedata.category(c)[0] in 'LM'
            or unicodedata.category(c) in ('Nd', 'Nl')]
    return ''.join(kept).replace(' ', '-')


def anchors(text):
    """Return every anchor of a Markdown page: its headings' slugs and HTML anchors."""
    found, counts = set(), {}
    previous = ''
    for _, line in _prose_lines(text):
        heading = None
        match = ATX.match(line)
        if match:
            heading = match.group(2)
        elif (SETEXT.match(line) and previous.strip() and not previous.lstrip().startswith(
                ('|', '-', '*', '>', '#')) and not line.startswith('|')):
            heading = previous.strip()
        if heading is not None:
            base = slug(heading)
            count = counts.get(base, 0)
            counts[base] = count + 1
            found.add(base if count == 0 else f'{base}-{count}')
        found.update(HTML_ANCHOR.findall(line))
        previous = line
    return found


def links(text):
    """Yield (line number, target) of every link and image outside code."""
    for number, line in _prose_lines(text):
        line = INLINE_CODE.sub('', line)
        for pattern in (LINK, REFERENCE, HTML_LINK):
            for match in pattern.finditer(line):
                yield number, match.group(1)


def _is_external(target):
    return bool(re.match(r'^[a-zA-Z][a-zA-Z0-9+.-]*:', target)) or target.startswith('//')


def test_slug_follows_github():
    assert slug('Timing and pairing') == 'timing-and-pairing'
    assert slug('monitor: attitude estimate') == 'monitor-attitude-estimate'
    assert slug("The divergence guard's defaults") == 'the-divergence-guards-defaults'
    assert slug('1. Batch core') == '1-batch-core'
    assert slug('Use it with `observer_node` (raw IMU)') == 'use-it-with-observer_node-raw-imu'
    assert slug('Figure 2 and Table 1: the observers (Section 3.2)') == (
        'figure-2-and-table-1-the-observers-section-32')
    assert slug('The certificate on S³') == 'the-certificate-on-s'
    assert slug('With ROS 2 installed: colcon and ros2 run') == (
        'with-ros-2-installed-colcon-and-ros2-run')
    assert anchors('# A\n## A\n```\n# not a heading\n```\nB\n---\n') == {'a', 'a-1', 'b'}


def test_relative_links_resolve_to_files_and_headings():
    broken = []
    for page in _pages():
        text = _read(page)
        for number, target in links(text):
            if not target or _is_external(target):
                continue
            path, _, anchor = target.partition('#')
            resolved = os.path.normpath(os.path.join(os.path.dirname(page), path)) \
                if path else page
            where = f'{_name(page)}:{number}: {target}'
            if not os.path.exists(resolved):
                broken.append(f'{where}: no file {_name(resolved)}')
            elif anchor and resolved.endswith('.md'):
                if anchor not in anchors(_read(resolved)):
                    broken.append(f'{where}: no heading with the anchor #{anchor} in '
                                  f'{_name(resolved)}')
    assert not broken, 'broken links:\n' + '\n'.join(broken)


# Generated tables -----------------------------------------------------------

def test_parameter_tables_equal_the_specs():
    from docgen.parameter_tables import PAGE, render

    path = os.path.join(DOCS, PAGE)
    text = _read(path)
    assert render(text) == text, (
        f'the parameter tables of docs/{PAGE} differ from the parameter specs: '
        'run  python -m ext_observer docs  (or make docs) and commit the page')


def test_the_state_table_equals_the_state():
    from docgen.parameter_tables import LAYOUT_PAGE, render_state
    from ext_observer.core.ahrs.ahrs_state import STATE

    text = _read(os.path.join(DOCS, LAYOUT_PAGE))
    assert render_state(text) == text, (
        f'the state table of docs/{LAYOUT_PAGE} differs from ahrs_state.STATE: '
        'run  python -m ext_observer docs  (or make docs) and commit the page')
    # Every field, with its unit and meaning, is on the page.
    for path, unit, meaning, size in STATE.fields():
        assert f'| `{".".join(path)}` | {size} | {unit} | {meaning} |' in text


def test_docs_command_checks_and_regenerates(tmp_path, capsys):
    from ext_observer.__main__ import main
    from docgen.parameter_tables import PAGE

    text = _read(os.path.join(DOCS, PAGE))
    stale = re.sub(r'(\| `rate_hz` \| double \| )`[^`]*`', r'\1`0.0`', text)
    assert stale != text
    (tmp_path / PAGE).write_text(stale, encoding='utf-8')
    assert main(['docs', '--docs', str(tmp_path), '--check']) == 1
    assert (tmp_path / PAGE).read_text(encoding='utf-8') == stale
    assert main(['docs', '--docs', str(tmp_path)]) == 0
    assert (tmp_path / PAGE).read_text(encoding='utf-8') == text
    assert main(['docs', '--docs', str(tmp_path), '--check']) == 0
    (tmp_path / PAGE).write_text('# Parameters\n', encoding='utf-8')
    assert main(['docs', '--docs', str(tmp_path)]) == 2
    assert 'no generated table of gyro' in capsys.readouterr().err


# Diagnostics and faults -----------------------------------------------------

def test_every_diagnostics_key_is_documented():
    from ext_observer.nodes.monitor_node import COUNTER_KEYS, DIAGNOSTIC_KEYS, ERROR_KEYS
    from ext_observer.nodes.observer_node import DROP_REASONS, GUARD_REASONS, RESET_CAUSES

    text = _read(os.path.join(DOCS, 'diagnostics.md'))
    missing = [key for key in DIAGNOSTIC_KEYS + ERROR_KEYS + COUNTER_KEYS
               + DROP_REASONS + GUARD_REASONS + RESET_CAUSES
               if f'`{key}`' not in text]
    assert not missing, f'not on docs/diagnostics.md: {missing}'


def test_every_fault_counter_has_a_row_in_the_fault_table():
    from ext_observer.nodes.monitor_node import DROP_REASONS as MONITOR_DROP_REASONS
    from ext_observer.nodes.observer_node import DROP_REASONS, GUARD_REASONS, RESET_CAUSES

    rows = [line for _, line in _prose_lines(_read(os.path.join(DOCS, 'faults.md')))
            if line.startswith('|')]
    named = set()
    for row in rows:
        cells = re.split(r'(?<!\\)\|', row.strip().strip('|'))
        if len(cells) >= 3:
            named.update(re.findall(r'`([\w*:<>]+)`', cells[2]))
    counters = ([f'dropped_{reason}' for reason in DROP_REASONS + MONITOR_DROP_REASONS]
                + [f'reinitialized_{reason}' for reason in GUARD_REASONS]
                + [f'resets_{cause}' for cause in RESET_CAUSES])
    missing = [counter for counter in counters
               if not any(fnmatch.fnmatchcase(counter, name) for name in named)]
    assert not missing, f'no row of the fault table in docs/faults.md names {missing}'


def _test_functions(path):
    return set(re.findall(r'^(?:async )?def (test_\w+)', _read(path), re.MULTILINE))


def test_cited_tests_exist():
    missing = []
    for page in _pages():
        text = INLINE_CODE.sub(lambda match: f' {match.group(2)} ', _read(page))
        for file, name in re.findall(r'\b(test_[\w*]+\.py)(?:::([\w*…]+))?', text):
            paths = [path for folder in ('test', 'bench')
                     for path in glob.glob(os.path.join(REPO, folder, '**', file), recursive=True)]
            if not paths:
                missing.append(f'{_name(page)}: {file}')
            elif name:
                functions = set().union(*map(_test_functions, paths))
                if not fnmatch.filter(functions, name.replace('…', '*')):
                    missing.append(f'{_name(page)}: {file}::{name}')
    assert not missing, 'cited tests that do not exist:\n' + '\n'.join(missing)


# The index and the README ---------------------------------------------------

def test_every_page_is_in_the_index_and_opens_with_a_sentence():
    index = os.path.join(DOCS, 'README.md')
    listed = {os.path.normpath(os.path.join(DOCS, target.partition('#')[0]))
              for _, target in links(_read(index)) if not _is_external(target)}
    for page in sorted(glob.glob(os.path.join(DOCS, '*.md'))):
        if page != index:
            assert page in listed, f'{_name(page)} is not listed in docs/README.md'
        lines = [line for _, line in _prose_lines(_read(page)) if line.strip()]
        assert lines[0].startswith('# '), f'{_name(page)} has no title'
        first = lines[1] if len(lines) > 1 else ''
        assert first[:1].isalpha(), (
            f'{_name(page)} should open with a sentence on what it is for, '
            f'not {first[:40]!r}')


def test_readme_is_short_and_keeps_the_quick_start():
    text = _read(README)
    assert len(text.splitlines()) < README_MAX_LINES, (
        f'README.md has {len(text.splitlines())} lines; keep it under {README_MAX_LINES} '
        'and move the details to a page of docs/')
    assert '```shell\nmake demo\nmake test\n```' in text


@pytest.mark.parametrize('page', ['README.md', 'docs/README.md'])
def test_broad_data_is_credited(page):
    text = _read(os.path.join(REPO, page))
    if 'BROAD' in text:
        assert 'Laidig et al. 2021' in text and 'CC BY 4.0' in text


def test_no_page_holds_a_path_of_the_machine_that_made_it():
    found = [f'{os.path.relpath(page, REPO)}:{text[:match.start()].count(chr(10)) + 1}: '
             f'{text[match.start():match.start() + 40].split()[0]}'
             for page in _pages() for text in [_read(page)]
             for match in MACHINE_PATH.finditer(text)]
    assert not found, f'paths of one machine (write them relative to the repository): {found}'
    # The pattern finds what it must, and not a relative path or ROS's own.
    assert MACHINE_PATH.search('--data /work/shared/broad') and MACHINE_PATH.search(
        '`/tmp/bench-1/compiled.json`') and MACHINE_PATH.search(REPO + '/docs') and \
        MACHINE_PATH.search('file:///tmp/mirror.git')
    assert not MACHINE_PATH.search('../shared/broad ../../tmp/x /opt/ros/jazzy/setup.bash')


def test_issue_numbers_are_flagged_unless_another_project_is_named():
    # Split literals, so that this file names no issue itself.
    assert [m for _, m in issue_numbers(
        'iss' 'ue 18\'s bounds; Iss' 'ues 27; see (' '#31), or ' '#6. imu_tools #3, '
        'dlaidig/vqf #25, `CCNYRoboticsLab/imu_tools #195`, vqf iss' 'ue 25; [x](#6-raw-imu); '
        '4 issues')] == ['iss' 'ue 18', 'Iss' 'ues 27', '#' '31', '#' '6']


def test_no_issue_of_this_project_is_named_by_number():
    found = []
    for folder in ('ext_observer', 'test', 'docs'):
        for root, _, files in os.walk(os.path.join(REPO, folder)):
            for file in files:
                path = os.path.join(root, file)
                if not file.endswith(('.py', '.md', '.yaml', '.toml', '.txt')):
                    continue
                found += [f'{_name(path)}:{line}: {mention}'
                          for line, mention in issue_numbers(_read(path))]
    assert not found, 'name the goal or fault, not its issue:\n' + '\n'.join(found)
