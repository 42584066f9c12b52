"""
The arithmetic behind the paper's figures (``core/paper/experiments.py``):
the accuracy limit, the fitted contraction, row names, Table 1's statistics,
and small runs of both experiments (same seed, same numbers; every observer
sees the same inputs).
"""

import math

import numpy as np
from numpy.testing import assert_array_equal
import pytest

from ext_observer.core.paper.experiments import (accuracy_limit, error_table, fit_contraction,
                                                 manifold_convergence, ObserverSpec,
                                                 observer_runs, row_name)


def test_the_accuracy_limit_is_the_mean_of_chi3_over_root_k():
    assert accuracy_limit(0.1, 100) == pytest.approx(0.1 * 1.5957691216 / 10, rel=1e-9)
    assert accuracy_limit(0.2, 400) == pytest.approx(accuracy_limit(0.1, 100))
    # E[χ₃] by sampling.
    rng = np.random.default_rng(0)
    mean = np.linalg.norm(rng.standard_normal((200000, 3)), axis=1).mean()
    assert accuracy_limit(1.0, 1) == pytest.approx(mean, rel=0.005)


def test_a_geometric_sequence_fits_its_factor_and_zeros_are_skipped():
    values = 3.0 * 0.8 ** np.arange(20)
    assert fit_contraction(values) == pytest.approx(0.8, rel=1e-12)
    values[5] = 0.0
    assert fit_contraction(values) == pytest.approx(0.8, rel=1e-12)


def test_row_names_and_the_table_of_one_observer():
    assert row_name('extended') == 'extended'
    assert row_name('plain', 'rotating') == 'plain-rotating'
    assert ObserverSpec('projected', 'scheduled').name == 'projected-scheduled'
    k = np.arange(6, dtype=float)[:, None] * np.ones((1, 4))
    k[-1] = [1.0, 2.0, 3.0, 6.0]
    k[2] = 50.0  # epoch `after` itself: not in Max and Min
    histories = {'error': k, 'residual': 2 * k, 'distance': -k, 'angle': k + 1}
    table = error_table(histories, after=2)
    assert table['error'] == {'mean': 3.0, 'std': pytest.approx(math.sqrt(3.5)),
                              'max': 6.0, 'min': 1.0}
    assert table['distance']['max'] == 12.0
    assert table['euclidean_distance']['min'] == -6.0
    assert table['angle']['min'] == 2.0


def test_the_experiments_are_reproducible_and_share_their_inputs():
    a = manifold_convergence(runs=20, epochs=15, seed=3)
    b = manifold_convergence(runs=20, epochs=15, seed=3)
    assert_array_equal(a['residual'], b['residual'])
    assert a['residual'].shape == (16, 20)
    assert a['residual'][-1].mean() < a['residual'][0].mean()
    specs = [ObserverSpec('extended'), ObserverSpec('extended')]
    runs = observer_runs(specs[:1], runs=10, epochs=5, seed=1)
    assert set(runs) == {'extended'}
    assert set(runs['extended']) >= {'error', 'residual', 'distance', 'angle'}
    assert runs['extended']['error'].shape == (6, 10)
    again = observer_runs([ObserverSpec('extended'), ObserverSpec('plain')], runs=10,
                          epochs=5, seed=1)
    assert_array_equal(again['extended']['error'], runs['extended']['error'])
