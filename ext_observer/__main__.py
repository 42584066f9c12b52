"""
Command line of ext_observer: ``python -m ext_observer <command>``.

Commands
--------
gains
    The gain certificate of Theorem 1 on S³ (admissible α).
reproduce
    The paper's Figure 1, Figure 2 and Table 1.
demo
    The gyro → observer → monitor pipeline in one process.
docs
    Regenerate the parameter tables of docs/parameters.md (in a clone only).
broad
    The raw-IMU estimator and the anchors on the BROAD recordings.
bag, csv
    The raw-IMU estimator on a rosbag2 bag or a CSV file (docs/own_data.md).
example-data
    A bag and a CSV made from a shipped BROAD excerpt.
calibrate
    The magnetometer's hard- and soft-iron calibration from a recording, as a
    params file for imu_filter_node (docs/calibration.md).
"""

import argparse
import json
import sys


def _gains(args):
    from ext_observer.core import optimal_delta, s3_certificate
    cert = s3_certificate(args.epsilon, args.delta, alpha=args.alpha)
    result = {key: value for key, value in cert.to_dict().items()
              if value is not None}
    if args.optimize_delta:
        result['delta_opt'], result['alpha_max_opt'] = optimal_delta(args.epsilon)
    if args.json:
        print(json.dumps(result, indent=2))
        return 0
    print(f'Gain certificate on S³, V(x) = (x̄x − 1)², epsilon = {cert.epsilon}, '
          f'delta = {cert.delta}')
    print(f'  L = max ‖∇V‖ on V⁻¹([0, ε])      = {cert.L:.6g}')
    print(f'  d = sup λ_max(D²V) on S_δ         = {cert.d:.6g}')
    print(f'  b with ‖∇V‖² ≥ b V                = {cert.b:.6g}')
    print(f'  alpha_max = min(2/d, δ/L)         = {cert.alpha_max:.6g}')
    if cert.alpha is not None:
        print(f'  alpha = {cert.alpha:g}: c = α − α²d/2 = {cert.c:.6g}, '
              f'certified factor 1 − bc = {cert.factor:.6g} per step on V')
    if args.optimize_delta:
        print(f'  best delta = {result["delta_opt"]:.6g} gives alpha_max = '
              f'{result["alpha_max_opt"]:.6g}')
    return 0


def _positive_float(text):
    value = float(text)
    if not value > 0.0:
        raise argparse.ArgumentTypeError(f'must be positive, got {text}')
    return value


def build_parser():
    """Return the argument parser of ``python -m ext_observer``."""
    parser = argparse.ArgumentParser(
        prog='python -m ext_observer',
        description='Transversally stable extension observers on S³.')
    sub = parser.add_subparsers(dest='command', required=True)

    gains = sub.add_parser('gains', help='gain certificate of Theorem 1 on S³')
    gains.add_argument('--epsilon', type=_positive_float, default=0.5,
                       help='sublevel of V, in (0, 1) (default 0.5)')
    gains.add_argument('--delta', type=_positive_float, default=0.059,
                       help='margin of S_delta (default 0.059, the paper)')
    gains.add_argument('--alpha', type=_positive_float, default=None,
                       help='also give c and the certified factor for this α')
    gains.add_argument('--optimize-delta', action='store_true',
                       help='also find the delta that maximizes alpha_max')
    gains.add_argument('--json', action='store_true', help='print JSON')
    gains.set_defaults(func=_gains)

    reproduce = sub.add_parser(
        'reproduce', add_help=False,
        help="the paper's Figure 1, Figure 2 and Table 1 (see reproduce -h)")
    reproduce.set_defaults(func=None, module='ext_observer.paper.reproduce')
    demo = sub.add_parser(
        'demo', add_help=False,
        help='gyro → observer → monitor pipeline (see demo -h)')
    demo.set_defaults(func=None, module='ext_observer.demo')
    docs = sub.add_parser(
        'docs', add_help=False,
        help='regenerate the parameter tables of docs/parameters.md (in a clone: '
             'docgen/ is not installed; see docs -h)')
    docs.set_defaults(func=None, module='docgen.parameter_tables')
    broad = sub.add_parser(
        'broad', add_help=False,
        help='the raw-IMU estimator and the anchors on BROAD (see broad -h)')
    broad.set_defaults(func=None, module='ext_observer.broad')
    for name, module, text in (
            ('bag', 'bag', 'the raw-IMU estimator on a rosbag2 bag, MCAP or sqlite3'),
            ('csv', 'csvio', 'the raw-IMU estimator on a CSV recording'),
            ('example-data', 'example_data', 'a bag and a CSV made from a BROAD excerpt'),
            ('calibrate', 'calibrate',
             'the magnetometer calibration learned from a recording, as a params file')):
        sub.add_parser(name, add_help=False, help=f'{text} (see {name} -h)').set_defaults(
            func=None, module=f'ext_observer.recordings.{module}')
    return parser


def main(argv=None):
    """Run the command line; return the exit code."""
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser()
    args, rest = parser.parse_known_args(argv)
    if args.func is None:
        # reproduce, demo, docs and broad parse their own options.
        import importlib
        package, _, module = args.module.partition('.')
        if package != 'docgen':
            return importlib.import_module(args.module).main(rest)
        from ext_observer.source_tree import docgen
        try:
            writer = docgen(module)
        except RuntimeError as error:
            print(f'error: {error}', file=sys.stderr)
            return 2
        return writer.main(rest)
    if rest:
        parser.error(f'unrecognized arguments: {" ".join(rest)}')
    try:
        return args.func(args)
    except ValueError as error:
        print(f'error: {error}', file=sys.stderr)
        return 2


def leave(code):
    """
    End this process with ``code``: at once where numba was loaded.

    Unloading numba's compiled kernels makes the interpreter's teardown
    slow (about 0.15 s of the broad command's 1.5 s, measured): once the
    command is done, its output flushed and the exit handlers run, the
    process leaves without it. Files the commands write are closed where
    they are written.
    """
    code = 0 if code is None else code
    if 'numba' not in sys.modules or not isinstance(code, int):
        sys.exit(code)
    import atexit
    import logging
    import os
    atexit._run_exitfuncs()  # the multiprocessing and logging handlers
    logging.shutdown()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


if __name__ == '__main__':
    leave(main())
