"""
``python -m bench.smooth_cost``: what ``bag --smooth`` costs beside the online bag command.

Writes a bag of ``--minutes`` at ``--rate`` Hz (BROAD trial 01's excerpt looped,
:func:`ext_observer.recordings.example_data.excerpt`, a field every
``--mag-every`` samples) into ``--work``, then runs the bag command on it,
online or ``--smooth``, in a fresh interpreter each (so that each peak RSS
is its own): CPU time of the command's process and of its children, the
smoother's own CPU time, and the peak RSS of both (``resource.getrusage``).
Run it at two lengths to get the growth per minute (docs/own_data.md).
"""

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import time

__all__ = ['main', 'measure']


def measure(bag, out, smooth):
    """Run the bag command once, here; return its figures (s, MB)."""
    from ext_observer.recordings import smoothing
    from ext_observer.recordings.bag import run_bag
    spent = {'smoother_cpu_s': 0.0}
    inner = smoothing.smoothed_attitude

    def timed(*args, **kwargs):
        start = time.process_time()
        result = inner(*args, **kwargs)
        spent['smoother_cpu_s'] = time.process_time() - start
        return result

    smoothing.smoothed_attitude = timed
    start = time.process_time()
    with open(os.devnull, 'w', encoding='utf-8') as quiet:
        run = run_bag(bag, out, smooth=smooth, progress=quiet)
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    spent.update(samples=run.recording.counts['imu_samples'],
                 cpu_s=time.process_time() - start,
                 children_cpu_s=children.ru_utime + children.ru_stime,
                 peak_rss_mb=resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024,
                 children_peak_rss_mb=children.ru_maxrss / 1024)
    shutil.rmtree(out, ignore_errors=True)
    return spent


def main(argv=None):
    parser = argparse.ArgumentParser(prog='python -m bench.smooth_cost', description=__doc__)
    parser.add_argument('--minutes', type=float, default=5.0)
    parser.add_argument('--rate', type=float, default=1000.0)
    parser.add_argument('--mag-every', type=int, default=10)
    parser.add_argument('--work', required=True, help='a folder for the bags')
    parser.add_argument('--once', choices=('write', 'online', 'smooth'),
                        help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    bag = os.path.join(args.work, f'in_{args.minutes:g}min_{args.rate:g}hz')
    if args.once == 'write':
        from ext_observer.recordings.example_data import excerpt, load_excerpt, write_bag
        os.makedirs(args.work, exist_ok=True)
        write_bag(bag, excerpt(load_excerpt(), seconds=60.0 * args.minutes, rate=args.rate,
                               mag_every=args.mag_every), 'mcap', reference=False)
        return 0
    if args.once:
        figures = measure(bag, bag + f'_{args.once}', args.once == 'smooth')
        print(json.dumps(figures))
        return 0
    # Each step in its own interpreter started from this small one: Linux keeps a
    # process's peak RSS across exec, so a measuring process must not be forked from one
    # that held the recording.
    steps = ([] if os.path.exists(bag) else ['write']) + ['online', 'smooth']
    for step in steps:
        done = subprocess.run([sys.executable, '-m', 'bench.smooth_cost', '--once', step,
                               '--minutes', str(args.minutes), '--rate', str(args.rate),
                               '--mag-every', str(args.mag_every), '--work', args.work],
                              check=True, capture_output=True, text=True)
        if step != 'write':
            print(f'{args.minutes:g} min at {args.rate:g} Hz, {step}: {done.stdout.strip()}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
