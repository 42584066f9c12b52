"""
``python -m bench.load``: the node on a busy machine, with the samples it loses.

Through DDS (:mod:`bench.load_dds`): one BROAD trial replayed into
``imu_filter_node`` at several times real time, the field at the IMU's rate
and at 100 Hz (9D) or none (6D), on the machine as it is and with every
core busy; written to ``docs/load.md`` (:mod:`docgen.load_page`) with
``--docs docs``. The estimate
with samples removed in batch was an experiment (``bench.load_batch``, in
bench/ up to commit 7319e4b); its figures are in docs/raw_imu.md.

``--trial 09 --seconds 60 --speeds 1 2 4`` is a short run; without options
the whole trial.
Progress goes to stderr, the page to stdout. Timings never fail the run.
"""

import argparse
import os
import sys

from bench import load_dds, machine
from bench.machine import log
from bench.procs import REPO
from ext_observer.broad.data import shown_command

DEFAULT_TRIAL = '09'
# Added to each case's replay time in the estimate printed first, s (the
# node's start, connection and drain).
CASE_OVERHEAD = 12.0


# --- running -----------------------------------------------------------------

def cut(trial, start=0.0, seconds=None):
    """The part of ``trial`` from ``start`` s on, ``seconds`` long (None: to its end)."""
    from ext_observer.broad.data import Trial
    first = int(round(start * trial.rate))
    last = len(trial) if seconds is None else first + int(round(seconds * trial.rate))
    part = slice(first, last)
    return Trial(trial.name, trial.gyr[part], trial.acc[part], trial.mag[part],
                 trial.quat[part], trial.movement[part], trial.rate)


def run_dds(args):
    """The DDS run's result: the trial, its rows (or ``missing``)."""
    from ext_observer.broad.data import data_dir, find_trials, HOW_TO_GET, load_trial
    try:
        name, path = find_trials(data_dir(args.data), [args.trial])[0]
    except ValueError:
        return {'missing': f'No BROAD trial `{args.trial}` found ({HOW_TO_GET}).'}
    trial = cut(load_trial(path, name), args.start, args.seconds)
    case_list = load_dds.cases(args.speeds, args.fields, args.loads, args.modes)
    estimate = sum(len(trial) / trial.rate / c[1] + CASE_OVERHEAD for c in case_list)
    log(f'DDS: {len(case_list)} cases on {name} ({len(trial) / trial.rate:.0f} s), about '
         f'{estimate / 60:.0f} min')
    rows = load_dds.dds_rows(trial, case_list, args.log_dir, progress=log)
    return {'trial': {'name': name, 'samples': len(trial), 'rate': trial.rate,
                      'seconds': len(trial) / trial.rate, 'movement': int(trial.movement.sum()),
                      'start': args.start},
            'rows': rows}


def _field_rate(text):
    return 'imu' if text == 'imu' else float(text)


def build_parser():
    """The parser of ``python -m bench.load``."""
    parser = argparse.ArgumentParser(prog='python -m bench.load', description=__doc__.split(
        '\n\n')[0].strip())
    parser.add_argument('--data', help='folder of BROAD\'s HDF5 files (default: as make broad)')
    parser.add_argument('--trial', default=DEFAULT_TRIAL,
                        help=f'the trial (name or prefix; default {DEFAULT_TRIAL})')
    parser.add_argument('--start', type=float, default=0.0,
                        help='replay the trial from this second on (default 0)')
    parser.add_argument('--seconds', type=float,
                        help='replay only this many seconds of the trial (default: to its end)')
    parser.add_argument('--speeds', type=float, nargs='+', default=list(load_dds.SPEEDS),
                        help='times real time')
    parser.add_argument('--fields', type=_field_rate, nargs='+',
                        default=list(load_dds.FIELD_RATES),
                        help='9D field rates: imu (after every sample) or Hz')
    parser.add_argument('--loads', nargs='+', choices=load_dds.LOADS,
                        default=list(load_dds.LOADS))
    parser.add_argument('--modes', nargs='+', choices=load_dds.MODES,
                        default=list(load_dds.MODES))
    parser.add_argument('--docs', metavar='DIR', help='write DIR/load.md')
    machine.add_page_arguments(parser)
    parser.add_argument('--note', help='a sentence for "How it was made" (the machine\'s state)')
    parser.add_argument('--log-dir', default=os.path.join(REPO, 'out', 'bench'),
                        help='the node\'s and the recorder\'s stderr')
    return parser


def main(argv=None):
    """Run the cases asked for; print the page, write it with ``--docs``; return 0."""
    argv = sys.argv[1:] if argv is None else list(argv)
    from docgen import load_page
    args = build_parser().parse_args(argv)

    return machine.page_main(args, shown_command(['python -m bench.load', *argv]),
                             lambda: {'note': args.note, 'dds': run_dds(args)},
                             load_page.render, _page(args))

def _page(args):
    return os.path.join(args.docs, 'load.md') if args.docs else None


if __name__ == '__main__':
    sys.exit(main())
