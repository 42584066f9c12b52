"""
BROAD's recordings: where they are, how one is read, how they are grouped.

A trial is one HDF5 file with ``imu_gyr`` (rad/s), ``imu_acc`` (m/s²),
``imu_mag`` (µT), ``opt_quat`` (optical reference, sensor → ENU,
``(w, x, y, z)``, NaN in gaps), ``movement`` (the scored samples) and the
attribute ``sampling_rate`` (Hz). BROAD's ``trials.json`` names the groups of
each trial; without it the groups are read from the file names.

The folder (:func:`data_dir`): the one given, else
``$EXT_OBSERVER_BROAD_DATA``, else ``data/broad`` (where ``make broad-data``
puts it), else ``../shared/broad``, the last two beside this source tree.
h5py is needed only to read the files (requirements-test.txt).
"""

import fnmatch
import glob
import json
import math
import os
import pickle

import numpy as np

ENV_VAR = 'EXT_OBSERVER_BROAD_DATA'
# The folder that holds the ext_observer package: in a checkout, the one
# with the Makefile.
TREE = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
# Looked for in this order, relative to TREE, when no folder is named.
DEFAULT_DIRS = ('data/broad', '../shared/broad')
HOW_TO_GET = ('make broad-data fetches it into data/broad; or give --data DIR or set '
              f'{ENV_VAR}')

# Group names of BROAD's trials.json, in its order, for the fallback that
# reads them from the file names.
_NAME_GROUPS = (
    ('undisturbed', 1), ('rotation', 2), ('translation', 2), ('combined', 2),
    ('slow', 2), ('fast', 2), ('no_breaks', 2), ('with_breaks', 2),
    ('disturbed', 1), ('tapping', 2), ('vibration', 2), ('stationary_magnet', 2),
    ('attached_magnet', 2), ('office_environment', 2), ('mixed', 2),
)


# --- the folder ------------------------------------------------------------

def _hdf5_files(folder):
    return sorted(glob.glob(os.path.join(folder, '*.hdf5'))
                  + glob.glob(os.path.join(folder, '*.h5')))


def has_trials(folder):
    """Return whether ``folder`` holds HDF5 files, directly or under ``data_hdf5/``."""
    return any(_hdf5_files(f) for f in (folder, os.path.join(folder, 'data_hdf5')))


def data_dir(given=None):
    """
    Return the folder of BROAD's HDF5 files.

    Parameters
    ----------
    given : str, optional
        A folder named by the user (``--data``): returned as it is.

    Returns
    -------
    str
        ``given``, else ``$EXT_OBSERVER_BROAD_DATA`` (as it is: a folder
        named on purpose is not replaced by another), else the first of
        :data:`DEFAULT_DIRS` that holds HDF5 files.

    Raises
    ------
    ValueError
        When nothing is named and no default folder holds the files; the
        message says how to get them.

    """
    if given:
        return given
    named = os.environ.get(ENV_VAR)
    if named:
        return named
    for relative in DEFAULT_DIRS:
        folder = os.path.normpath(os.path.join(TREE, relative))
        if has_trials(folder):
            return folder
    raise ValueError(f'no BROAD data in {" nor ".join(DEFAULT_DIRS)} (beside {TREE}): '
                     f'{HOW_TO_GET}')


def shown_path(path):
    """Return ``path`` as a page shows it: relative to the tree (the reader's folders differ)."""
    return os.path.relpath(os.path.abspath(path), TREE).replace(os.sep, '/')


def shown_command(words):
    """Return the command ``words`` as a page shows it: absolute paths as :func:`shown_path`.

    An argument holding a space (not the first word, the program) is shown in double
    quotes.
    """
    shown = []
    for word in words:
        option, equals, value = word.rpartition('=') if word.startswith('-') else ('', '', word)
        if os.path.isabs(value):
            value = shown_path(value)
        word = option + equals + value
        # An argument with a space (an anchor's name) quoted, so the command runs as shown.
        shown.append(f'"{word}"' if ' ' in word and shown else word)
    return ' '.join(shown).strip()


# --- the trials ------------------------------------------------------------

def _h5py():
    try:
        import h5py
    except ImportError as error:
        raise RuntimeError(
            'reading BROAD needs h5py: pip install h5py (or make test, which installs '
            'requirements-test.txt)') from error
    return h5py


class Trial:
    """
    One BROAD recording.

    Attributes
    ----------
    name : str
        The file name without its extension.
    gyr, acc, mag : ndarray, shape (N, 3)
        rad/s, m/s², µT, sensor frame.
    quat : ndarray, shape (N, 4)
        Optical reference, sensor → ENU, ``(w, x, y, z)``; NaN in gaps.
    movement : ndarray of bool, shape (N,)
        The samples that are scored.
    rate : float
        Sampling rate (Hz).

    """

    def __init__(self, name, gyr, acc, mag, quat, movement, rate):
        self.name = name
        self.gyr = np.ascontiguousarray(gyr, dtype=float)
        self.acc = np.ascontiguousarray(acc, dtype=float)
        self.mag = np.ascontiguousarray(mag, dtype=float)
        self.quat = np.asarray(quat, dtype=float)
        self.movement = np.asarray(movement, dtype=bool)
        self.rate = float(rate)
        n = len(self.gyr)
        for label, array, width in (('acc', self.acc, 3), ('mag', self.mag, 3),
                                    ('quat', self.quat, 4)):
            if array.shape != (n, width):
                raise ValueError(f'{name}: expected {label} of shape ({n}, {width}), '
                                 f'got {array.shape}')
        if self.movement.shape != (n,):
            raise ValueError(f'{name}: expected movement of shape ({n},), '
                             f'got {self.movement.shape}')
        if not (math.isfinite(self.rate) and self.rate > 0.0):
            raise ValueError(f'{name}: sampling rate must be positive, got {rate}')

    def __len__(self):
        return len(self.gyr)

    def head(self, seconds):
        """Return the first ``seconds`` of the trial (for quick checks)."""
        n = max(1, int(round(seconds * self.rate)))
        return Trial(self.name, self.gyr[:n], self.acc[:n], self.mag[:n],
                     self.quat[:n], self.movement[:n], self.rate)


def find_trials(data_dir, patterns=None):
    """
    Return the HDF5 files of BROAD in ``data_dir`` or ``data_dir/data_hdf5``.

    Parameters
    ----------
    data_dir : str
    patterns : list of str, optional
        Keep the trials whose name matches one of these (``fnmatch``
        patterns; a plain word matches as a prefix).

    Returns
    -------
    list of (str, str)
        (trial name, path), sorted by name.

    """
    paths = []
    for folder in (data_dir, os.path.join(data_dir, 'data_hdf5')):
        paths = _hdf5_files(folder)
        if paths:
            break
    if not paths:
        raise ValueError(f'no HDF5 files (*.hdf5) in {data_dir} nor in '
                         f'{os.path.join(data_dir, "data_hdf5")}')
    trials = [(os.path.splitext(os.path.basename(p))[0], p) for p in paths]
    if patterns:
        def wanted(name):
            return any(fnmatch.fnmatch(name, p) or name.startswith(p) for p in patterns)
        trials = [t for t in trials if wanted(t[0])]
        if not trials:
            raise ValueError(f'no trial matches {patterns}')
    return trials


_KEYS = ('imu_gyr', 'imu_acc', 'imu_mag', 'opt_quat', 'movement')


def _checked(f, path):
    """The sampling rate of an open trial file; ValueError naming what it lacks."""
    missing = [k for k in _KEYS if k not in f]
    if missing:
        raise ValueError(f'{path}: missing {missing}')
    if 'sampling_rate' not in f.attrs:
        raise ValueError(f'{path}: missing the attribute sampling_rate')
    return float(np.squeeze(f.attrs['sampling_rate']))


def load_trial(path, name=None):
    """Read one BROAD HDF5 file into a :class:`Trial`."""
    h5py = _h5py()
    name = name or os.path.splitext(os.path.basename(path))[0]
    with h5py.File(path, 'r') as f:
        rate = _checked(f, path)
        return Trial(name, *(f[k][()] for k in _KEYS), rate)


def load_trials(found, meanwhile=None):
    """
    Read trials into :class:`Trial` objects, while ``meanwhile()`` runs.

    The broad command passes the loading of its compiled kernels as
    ``meanwhile`` (numba's import and cache, about 0.4 s): where processes
    can fork, a child reads the files into memory shared with this process
    meanwhile (the shapes read first, the data written in place: nothing is
    copied back). The arrays are those :func:`load_trial` reads; an error
    of the reader is raised here, as :func:`load_trial` raises it.

    Parameters
    ----------
    found : list of (str, str)
        (trial name, path), as :func:`find_trials` returns them.
    meanwhile : callable, optional

    Returns
    -------
    list of Trial

    """
    if meanwhile is None or not hasattr(os, 'fork'):
        if meanwhile is not None:
            meanwhile()
        return [load_trial(path, name) for name, path in found]
    h5py = _h5py()
    from ext_observer.pipeline.batch import shared_arrays
    rates, specs = [], []
    for _, path in found:
        with h5py.File(path, 'r') as f:
            rates.append(_checked(f, path))
            specs += [(f[k].shape, f[k].dtype) for k in _KEYS]
    arrays = shared_arrays(specs)
    read_end, write_end = os.pipe()
    pid = os.fork()
    if pid == 0:  # the reader: fill the arrays, or say what failed
        status = 0
        try:
            os.close(read_end)
            for i, (_, path) in enumerate(found):
                with h5py.File(path, 'r') as f:
                    for j, k in enumerate(_KEYS):
                        if arrays[i * len(_KEYS) + j].size:
                            f[k].read_direct(arrays[i * len(_KEYS) + j])
        except BaseException as error:  # noqa: B036 (sent to the parent, raised there)
            status = 1
            with os.fdopen(write_end, 'wb') as pipe:
                pipe.write(pickle.dumps(_picklable(error)))
        os._exit(status)
    os.close(write_end)
    try:
        meanwhile()
    finally:
        with os.fdopen(read_end, 'rb') as pipe:
            failure = pipe.read()
        _, status = os.waitpid(pid, 0)
    if failure:
        raise pickle.loads(failure)
    if status:  # ended without a word (a signal): the arrays are not all read
        raise OSError(f'the process reading the trials ended abnormally (wait status {status})')
    k = len(_KEYS)
    return [Trial(name, *arrays[i * k:(i + 1) * k], rates[i])
            for i, (name, _) in enumerate(found)]


def _picklable(error):
    """``error`` where it pickles and unpickles; else an OSError that names it."""
    try:
        pickle.loads(pickle.dumps(error))
        return error
    except Exception:
        return OSError(f'{type(error).__name__}: {error}')


# --- the groups ------------------------------------------------------------

def groups_from_name(name):
    """
    Return the groups of a trial read from its file name.

    ``undisturbed`` or ``disturbed``, then the subgroup words (rotation,
    translation, combined, slow, fast, with/without breaks; tapping,
    vibration, stationary magnet, attached magnet, office, mixed).
    """
    words = name.lower()
    groups = ['all_trials']
    if 'undisturbed' in words:
        groups.append('undisturbed')
        groups += [w for w in ('rotation', 'translation', 'combined', 'slow', 'fast')
                   if w in words]
        groups.append('with_breaks' if 'with_breaks' in words else 'no_breaks')
    elif 'disturbed' in words:
        groups.append('disturbed')
        groups += [g for g, key in (('tapping', 'tapping'), ('vibration', 'vibration'),
                                    ('stationary_magnet', 'stationary_magnet'),
                                    ('attached_magnet', 'attached_magnet'),
                                    ('office_environment', 'office'), ('mixed', 'mixed'))
                   if key in words]
    return groups


def _trials_json(data_dir, hdf5_dir):
    """Return (spec, path) of the first ``trials.json`` found, or (None, None)."""
    # Beside the HDF5 files or one folder up; a clone of BROAD keeps it in
    # data_mat/ (make broad-data copies it to the top).
    candidates = [data_dir, os.path.join(data_dir, os.pardir)]
    if hdf5_dir:
        candidates += [os.path.join(hdf5_dir, os.pardir), hdf5_dir]
    candidates.append(os.path.join(data_dir, 'data_mat'))
    for folder in candidates:
        path = os.path.normpath(os.path.join(folder, 'trials.json'))
        if os.path.isfile(path):
            with open(path, encoding='utf-8') as f:
                return json.load(f), path
    return None, None


def find_groups(data_dir, names, hdf5_dir=None):
    """
    Return the groups of the trials: from BROAD's ``trials.json`` if found.

    ``trials.json`` is looked for in ``data_dir``, ``data_dir/..``, the
    folder that holds the HDF5 files and its parent, and
    ``data_dir/data_mat``; without it, or for a trial it does not list, the
    groups come from the file name.

    Returns
    -------
    dict
        ``order``: [(group, level)], the groups that have trials, in
        BROAD's order; ``members``: {group: [trial]}; ``source``: the
        ``trials.json`` used, or ``'file names'``.

    """
    spec, source = _trials_json(data_dir, hdf5_dir)
    if spec is not None:
        order = [(g['name'], int(g.get('level', 2))) for g in spec.get('groups', [])]
        listed = spec.get('trials', {})
    else:
        order = [('all_trials', 0)] + list(_NAME_GROUPS)
        listed = {}
        source = 'file names'
    known = {g for g, _ in order}
    members = {}
    for name in names:
        entry = listed.get(name)
        groups = entry['groups'] if entry else groups_from_name(name)
        for group in groups:
            if group not in known:
                order.append((group, 2))
                known.add(group)
            members.setdefault(group, []).append(name)
    order = [(g, level) for g, level in order if g in members]
    return {'order': order, 'members': members, 'source': source}
