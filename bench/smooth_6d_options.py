"""
``python -m bench.smooth_6d_options``: the smoothed 6D inclination's options, measured on BROAD.

Each option replaces one step of :func:`~ext_observer.core.ahrs.smoother.smooth_attitude`
(the inclination's window or the strapdown's rates) for the run, or corrects
the samples first; ``oracle`` options use the optical truth and bound what an
estimator could win that way. Scored as BROAD does (the inclination's RMS
over the movement samples), tuning and held-out trials apart. An experiment
kept for the record (docs/offline.md, "The 6D floor"), not a benchmark.
"""

import argparse
import contextlib
import json
import sys

import numpy as np

__all__ = ['main']


def _turn_up(q, mean):
    from ext_observer.core.quaternion import multiply, normalize
    up = mean / np.linalg.norm(mean, axis=1, keepdims=True)
    c = np.stack((1.0 + up[:, 2], up[:, 1], -up[:, 0], np.zeros(len(up))), axis=1)
    return normalize(multiply(normalize(c), q))


def _window(sigma=None, far=None, norm_s=None):
    """Inclination: σ (s), a far window (σ_far s, share), weights 1 / (1 + (Δ|f|/s)²)."""
    from ext_observer.core.ahrs.smooth_strapdown import rotate_rows
    from ext_observer.core.ahrs.smooth_windows import average
    from ext_observer.core.constants import STANDARD_GRAVITY

    def step(q, acc, axis, p):
        a_i = rotate_rows(q, acc)
        weight = np.ones(len(q))
        if norm_s is not None:
            size = np.linalg.norm(acc, axis=1)
            weight = 1.0 / (1.0 + np.square((size - STANDARD_GRAVITY) / norm_s))
        s = (p.window_acc if sigma is None else sigma) * axis.rate
        wide = None if far is None else (far[0] * axis.rate, far[1])
        return _turn_up(q, average(a_i, weight, s, wide))
    return step


def _laplace(tau):
    """Inclination: the force in I low-passed forward and backward, first order, ``tau`` s."""
    from ext_observer.core.ahrs.smooth_strapdown import rotate_rows

    def one_way(x, a):
        out = np.empty_like(x)
        state = x[0].copy()
        for k in range(len(x)):
            state += a * (x[k] - state)
            out[k] = state
        return out

    def step(q, acc, axis, p):
        a = 1.0 - np.exp(-1.0 / (tau * axis.rate))
        a_i = rotate_rows(q, acc)
        return _turn_up(q, one_way(one_way(a_i, a)[::-1], a)[::-1])
    return step


def _boxes(passes):
    """Inclination: ``passes`` box filters of the same total variance as the shipped window."""
    from ext_observer.core.ahrs.smooth_strapdown import rotate_rows
    from ext_observer.core.ahrs.smooth_windows import box

    def step(q, acc, axis, p):
        sigma = p.window_acc * axis.rate
        h = max(1, int(round(0.5 * (np.sqrt(1.0 + 12.0 * sigma ** 2 / passes) - 1.0))))
        num, den = rotate_rows(q, acc), np.ones(len(q))
        for _ in range(passes):
            num, den = box(num, h), box(den, h)
        return _turn_up(q, num / den[:, None])
    return step


def _intersected(gamma, tau=1.0, sigmas=(1.0, 1.5, 2.0, 3.0, 4.0)):
    """
    Inclination: per sample, the longest window whose confidence interval meets all shorter ones'.

    The intersection of confidence intervals (Katkovnik's ICI rule): the
    horizontal part of each window's averaged direction, ± ``gamma`` times
    its σ, the force's spread over the window as noise independent once every
    ``tau`` s.
    """
    from ext_observer.core.ahrs.smooth_strapdown import rotate_rows
    from ext_observer.core.ahrs.smooth_windows import average
    from ext_observer.core.constants import STANDARD_GRAVITY

    def step(q, acc, axis, p):
        a_i = rotate_rows(q, acc)
        n = len(q)
        one = np.ones(n)
        lo, hi = np.full((n, 2), -np.inf), np.full((n, 2), np.inf)
        alive = np.ones(n, dtype=bool)
        chosen = None
        for s in sigmas:
            mean = average(a_i, one, s * axis.rate)
            second = average(np.sum(a_i * a_i, axis=1)[:, None], one, s * axis.rate)[:, 0]
            spread = np.sqrt(np.maximum(second - np.sum(mean * mean, axis=1), 0.0))
            std = spread / STANDARD_GRAVITY * np.sqrt(tau / (2.0 * np.sqrt(np.pi) * s))
            u = mean[:, :2] / np.linalg.norm(mean, axis=1)[:, None]
            lo = np.maximum(lo, u - gamma * std[:, None])
            hi = np.minimum(hi, u + gamma * std[:, None])
            alive &= np.all(lo <= hi, axis=1)
            if chosen is None:
                chosen = mean.copy()
            else:
                chosen[alive] = mean[alive]
        return _turn_up(q, chosen)
    return step


def _balanced(ratio, whole=True, sigmas=(1.0, 1.5, 2.0, 3.0, 4.0, 6.0)):
    """
    Inclination: σ = ``window_acc`` × √(A / (Ω ``ratio``)), the nearest of ``sigmas``.

    The window that balances the linear acceleration's error (∝ A / σ) and
    the gyro's over the window (∝ Ω σ): ``A``, the force's spread in I over the
    shipped window (m/s²); ``Ω``, the mean rate over it (rad/s); ``whole``: both
    over the whole recording (one σ per trial), else per sample.
    """
    from ext_observer.core.ahrs.smooth_strapdown import rotate_rows
    from ext_observer.core.ahrs.smooth_windows import average
    grid = np.log(np.asarray(sigmas))

    def step(q, acc, axis, p):
        a_i = rotate_rows(q, acc)
        n = len(q)
        one = np.ones(n)
        s0 = p.window_acc * axis.rate
        mean = average(a_i, one, s0)
        second = average(np.sum(a_i * a_i, axis=1)[:, None], one, s0)[:, 0]
        spread = np.sqrt(np.maximum(second - np.sum(mean * mean, axis=1), 0.0))
        turn = average(np.linalg.norm(_GYR[0], axis=1)[:, None], one, s0)[:, 0]
        if whole:
            r = np.full(n, spread.mean() / max(turn.mean(), 1e-3))
        else:
            r = spread / np.maximum(turn, 0.05)
        target = np.log(p.window_acc * np.sqrt(r / ratio))
        pick = np.argmin(np.abs(target[:, None] - grid[None, :]), axis=1)
        out = np.empty_like(mean)
        for i, s in enumerate(sigmas):
            if (pick == i).any():
                out[pick == i] = average(a_i, one, s * axis.rate)[pick == i]
        return _turn_up(q, out)
    return step


# The gyro of the trial being scored, for _balanced.
_GYR = [None]


def _bias_regression(hp=20.0, prior=0.05, noise=0.005, tau=2.0, iterations=1):
    """
    An inclination step that first fits a body-frame accelerometer bias ``b`` (3).

    The averaged force in I, ``m(t) ≈ g u(t) + A(t) b`` (``A``: the rotations
    to I averaged over the same window; ``u``: I's vertical, slowly drifting):
    both high-passed over ``hp`` s, the horizontal parts regressed (noise
    ``noise`` rad per ``tau`` s, a prior σ ``prior`` m/s² on ``b``).
    """
    from ext_observer.core.ahrs.smooth_strapdown import matrices, rotate_rows
    from ext_observer.core.ahrs.smooth_windows import average
    plain = _window()

    def step(q, acc, axis, p):
        n = len(q)
        one = np.ones(n)
        s = p.window_acc * axis.rate
        b = np.zeros(3)
        a = average(matrices(q).reshape(n, 9), one, s).reshape(n, 3, 3)
        for _ in range(iterations):
            mean = average(rotate_rows(q, acc - b), one, s)
            g = np.linalg.norm(mean, axis=1)
            y = mean[:, :2] / g[:, None]
            x = a[:, :2, :] / g[:, None, None]
            y = y - average(y, one, hp * axis.rate)
            x = x - average(x.reshape(n, 6), one, hp * axis.rate).reshape(n, 2, 3)
            w = 1.0 / (tau * axis.rate * noise ** 2)
            h = w * np.einsum('nki,nkj->ij', x, x) + np.eye(3) / prior ** 2
            b = b + np.linalg.solve(h, w * np.einsum('nki,nk->i', x, y))
        return plain(q, acc - b, axis, p)
    return step


@contextlib.contextmanager
def _replaced(inclination=None, rates=None):
    import ext_observer.core.ahrs.smoother as smoother
    saved = smoother.inclination, smoother.strapdown
    if inclination is not None:
        smoother.inclination = inclination
    if rates is not None:
        smoother.strapdown = lambda rate, dt, first: saved[1](rates(rate), dt, first)
    try:
        yield
    finally:
        smoother.inclination, smoother.strapdown = saved


def _filled(q):
    """The reference with NaN samples held from the nearest finite one."""
    ok = np.isfinite(q).all(axis=1)
    k = np.arange(len(q))
    before = np.maximum.accumulate(np.where(ok, k, -1))
    after = np.minimum.accumulate(np.where(ok, k, len(q))[::-1])[::-1]
    return q[np.where(before < 0, after, before)]


def _truth_rest_bias(trial):
    """m/s² (3): the mean of ``f − g v_ref`` over quiet samples (an oracle)."""
    from bench.smooth_floor import verticals
    from ext_observer.core.constants import STANDARD_GRAVITY
    v = verticals(_filled(trial.quat))
    size = np.linalg.norm(trial.acc, axis=1)
    quiet = ((np.linalg.norm(trial.gyr, axis=1) < 0.3)
             & (np.abs(size - STANDARD_GRAVITY) < 0.3) & np.isfinite(trial.quat).all(axis=1))
    return (trial.acc - STANDARD_GRAVITY * v)[quiet].mean(axis=0)


def _truth_gyro_matrix(trial):
    """(3, 3): the truth's rates regressed on the gyro's (with an offset), movement only."""
    from ext_observer.core.quaternion import conjugate, multiply
    q = trial.quat
    d = multiply(conjugate(q[:-1]), q[1:])
    d = d * np.sign(d[:, :1])
    angle = 2.0 * np.arctan2(np.linalg.norm(d[:, 1:], axis=1), d[:, 0])
    axis_ = d[:, 1:] / np.maximum(np.linalg.norm(d[:, 1:], axis=1), 1e-12)[:, None]
    true_rate = axis_ * (angle * trial.rate)[:, None]
    mid = 0.5 * (trial.gyr[:-1] + trial.gyr[1:])
    use = (np.isfinite(true_rate).all(axis=1) & trial.movement[:-1] & trial.movement[1:])
    x = np.hstack([mid[use], np.ones((use.sum(), 1))])
    coef, *_ = np.linalg.lstsq(x, true_rate[use], rcond=None)
    return coef[:3].T


OPTIONS = {
    'shipped': {},
    'window 1 s': {'inclination': lambda: _window(1.0)},
    'window 1.5 s': {'inclination': lambda: _window(1.5)},
    'window 3 s': {'inclination': lambda: _window(3.0)},
    'window 4 s': {'inclination': lambda: _window(4.0)},
    'window 6 s': {'inclination': lambda: _window(6.0)},
    'window 1 s + 4 s ×0.5': {'inclination': lambda: _window(1.0, (4.0, 0.5))},
    'window 1.5 s + 4 s ×0.5': {'inclination': lambda: _window(1.5, (4.0, 0.5))},
    'window 1 s + 3 s ×1': {'inclination': lambda: _window(1.0, (3.0, 1.0))},
    'forward-backward low-pass τ 1 s': {'inclination': lambda: _laplace(1.0)},
    'forward-backward low-pass τ 1.5 s': {'inclination': lambda: _laplace(1.5)},
    'forward-backward low-pass τ 2 s': {'inclination': lambda: _laplace(2.0)},
    'forward-backward low-pass τ 3 s': {'inclination': lambda: _laplace(3.0)},
    '2 boxes': {'inclination': lambda: _boxes(2)},
    '3 boxes': {'inclination': lambda: _boxes(3)},
    '5 boxes': {'inclination': lambda: _boxes(5)},
    '8 boxes': {'inclination': lambda: _boxes(8)},
    'window per sample, ICI Γ 0.01': {'inclination': lambda: _intersected(0.01)},
    'window per sample, ICI Γ 0.03': {'inclination': lambda: _intersected(0.03)},
    'window per sample, ICI Γ 0.1': {'inclination': lambda: _intersected(0.1)},
    'window per sample, ICI Γ 2': {'inclination': lambda: _intersected(2.0)},
    'balanced window per trial, ratio 0.7': {'inclination': lambda: _balanced(0.7)},
    'balanced window per trial, ratio 1': {'inclination': lambda: _balanced(1.0)},
    'balanced window per trial, ratio 1.4': {'inclination': lambda: _balanced(1.4)},
    'balanced window per sample, ratio 0.7': {'inclination': lambda: _balanced(0.7, False)},
    'balanced window per sample, ratio 1': {'inclination': lambda: _balanced(1.0, False)},
    'balanced window per sample, ratio 1.4': {'inclination': lambda: _balanced(1.4, False)},
    'weights 1/(1+(Δ|f|/5)²)': {'inclination': lambda: _window(norm_s=5.0)},
    'weights 1/(1+(Δ|f|/20)²)': {'inclination': lambda: _window(norm_s=20.0)},
    'weights 1/(1+(Δ|f|/2)²)': {'inclination': lambda: _window(norm_s=2.0)},
    'acc bias regressed, hp 20 s': {'inclination': lambda: _bias_regression()},
    'acc bias regressed, hp 5 s, 3 rounds': {
        'inclination': lambda: _bias_regression(hp=5.0, iterations=3)},
    'rates (ω_k + ω_k+1)/2': {'rates': lambda r: np.vstack((0.5 * (r[1:] + r[:-1]), r[-1:]))},
    'rates (ω_k−1 + ω_k)/2': {'rates': lambda r: np.vstack((r[:1], 0.5 * (r[1:] + r[:-1])))},
    "bias 'both'": {'params': {'bias': 'both'}},
    'oracle: acc bias from the truth at rest': {'acc': _truth_rest_bias},
    "oracle: gyro matrix from the truth's rates": {'gyr': _truth_gyro_matrix},
}


def _errors(trial, option):
    """rad (N,): the inclination error at each sample, NaN where not scored."""
    import dataclasses
    from bench.smooth_floor import angles, verticals
    from ext_observer.core.ahrs.smoother import smooth_attitude, SmoothParams
    gyr, acc = np.asarray(trial.gyr, dtype=float), np.asarray(trial.acc, dtype=float)
    _GYR[0] = gyr
    if 'acc' in option:
        acc = acc - option['acc'](trial)
    if 'gyr' in option:
        gyr = gyr @ option['gyr'](trial).T
    p = dataclasses.replace(SmoothParams(), **option.get('params', {}))
    inclination = option['inclination']() if 'inclination' in option else None
    with _replaced(inclination, option.get('rates')):
        q, _ = smooth_attitude(gyr, acc, None, trial.rate, p)
    keep = trial.movement & np.isfinite(trial.quat).all(axis=1)
    return np.where(keep, angles(verticals(q), verticals(np.nan_to_num(trial.quat))), np.nan)


def _score(trial, option):
    e = _errors(trial, option)
    return float(np.degrees(np.sqrt(np.nanmean(e * e))))


def _block_oracle(trial, labels, block):
    """deg: the error with, per ``block`` s, the option among ``labels`` the truth likes best."""
    e2 = np.square([_errors(trial, OPTIONS[k]) for k in labels])
    size = max(1, int(round(block * trial.rate)))
    starts = np.arange(0, e2.shape[1], size)
    counts = np.add.reduceat(np.isfinite(e2[0]).astype(float), starts)
    sums = np.add.reduceat(np.nan_to_num(e2), starts, axis=1)
    return float(np.degrees(np.sqrt(sums.min(axis=0).sum() / counts.sum())))


def main(argv=None):
    parser = argparse.ArgumentParser(prog='python -m bench.smooth_6d_options',
                                     description=__doc__)
    parser.add_argument('--data', default=None, help='BROAD folder (default: as broad finds it)')
    parser.add_argument('--options', nargs='*', help='option names (default: all)')
    parser.add_argument('--blocks', nargs='*', type=float, default=[],
                        help='s: also the window chosen by the truth per block of this length')
    parser.add_argument('--json', help='write the per-trial figures here')
    args = parser.parse_args(argv)
    from ext_observer.broad.data import data_dir, find_trials, load_trial
    from ext_observer.broad.split import split_of
    trials = [load_trial(path, name) for name, path in find_trials(data_dir(args.data))]
    rows = {}
    for label in args.options or OPTIONS:
        rows[label] = {t.name: _score(t, OPTIONS[label]) for t in trials}
        means = [np.mean([v for n, v in rows[label].items() if s in (None, split_of(n))])
                 for s in ('tuning', 'held-out', None)]
        print(f'{label:42s} tuning {means[0]:.3f}° held-out {means[1]:.3f}° '
              f'all {means[2]:.3f}°', flush=True)
    windows = [k for k in OPTIONS if k.startswith('window ') and '+' not in k] + ['shipped']
    if all(k in rows for k in windows):
        best = {n: min(rows[k][n] for k in windows) for n in rows['shipped']}
        means = [np.mean([v for n, v in best.items() if s in (None, split_of(n))])
                 for s in ('tuning', 'held-out', None)]
        print(f'{"oracle: the best window per trial":42s} tuning {means[0]:.3f}° '
              f'held-out {means[1]:.3f}° all {means[2]:.3f}°')
    for block in args.blocks:
        label = f'oracle: the best window per {block:g} s'
        rows[label] = {t.name: _block_oracle(t, windows, block) for t in trials}
        means = [np.mean([v for n, v in rows[label].items() if s in (None, split_of(n))])
                 for s in ('tuning', 'held-out', None)]
        print(f'{label:42s} tuning {means[0]:.3f}° held-out {means[1]:.3f}° '
              f'all {means[2]:.3f}°')
    if args.json:
        with open(args.json, 'w', encoding='utf-8') as f:
            json.dump(rows, f, indent=1)
    return 0


if __name__ == '__main__':
    sys.exit(main())
