"""
The demo's own logic (``ext_observer/demo.py``) without starting it: its
options refused by what is wrong, estimates paired with the truths by the
nearest stamp. (The demo run and interrupted as a process:
``test_processes.py``.)
"""

import pytest

from ext_observer.demo import _pair_by_stamp, build_parser


def test_the_options_are_parsed_and_bad_ones_refused(capsys):
    parser = build_parser()
    args = parser.parse_args(['--steps', '20', '--initial-estimate', '1,0,0,0.5'])
    assert args.steps == 20 and args.initial_estimate == (1.0, 0.0, 0.0, 0.5)
    assert args.rate == 30.0 and args.variant == 'extended'
    for argv, reason in ((['--steps', '0'], 'must be positive, got 0'),
                         (['--rate', '-1'], 'must be positive, got -1'),
                         (['--initial-estimate', '1,0,0'], 'expected 4 numbers w,x,y,z'),
                         (['--initial-estimate', '1,a,0,0'], 'expected w,x,y,z')):
        with pytest.raises(SystemExit):
            parser.parse_args(argv)
        assert reason in capsys.readouterr().err


def test_each_truth_is_paired_with_the_nearest_estimate_within_the_tolerance():
    estimates = {100: 'a', 199: 'b', 201: 'c', 400: 'd'}
    truths = {0: 'x', 100: 'y', 200: 'z', 300: 'w'}
    assert _pair_by_stamp(estimates, truths, 1) == [(100, 100), (200, 199)]
    assert _pair_by_stamp(estimates, truths, 0) == [(100, 100)]
    assert _pair_by_stamp({198: 'a', 201: 'b'}, {200: 'x'}, 2) == [(200, 201)]
    assert _pair_by_stamp(estimates, truths, 100) == [(0, 100), (100, 100), (200, 199),
                                                      (300, 201)]
