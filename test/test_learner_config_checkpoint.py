"""Tests of config/clis.yaml loading (range checks naming the key) and of atomic checkpoints."""

from __future__ import annotations

import os
from pathlib import Path

from clis_base.params import ConfigError, config_dir, ros_parameters
from clis_learner.core import checkpoint as ckpt
from clis_learner.core.checkpoint import CheckpointError, load_checkpoint, save_checkpoint
from clis_learner.core.config import load_clis_params, params_hash
from clis_modules.core.modules import make_modules
import numpy as np
import pytest
import yaml

# results pinned bit for bit: tools/cpu_check.py runs these under each CPU kernel set
pytestmark = pytest.mark.bits

LANDMARKS = np.array([[1.5, 0.75], [-0.75, 1.5], [-1.5, -0.75], [0.75, -1.5]])


# ------------------------------------------------------------------------------ config

def test_default_config_is_the_paper_preset():
    p = load_clis_params()
    assert (p.common.gamma, p.common.beta, p.common.epsilon) == (0.995, 1.0, 0.2)
    assert (p.innate.value.alpha, p.view.value.alpha, p.place.value.alpha) == (0.1, 0.1, 0.1)
    assert (p.innate.period, p.view.period, p.place.period) == (0.25, 0.5, 1.2)
    assert (p.innate.n_rbf, p.view.n_theta * p.view.n_dist) == (9, 81)
    assert p.place.localization.cell_size == 0.15 and p.place.localization.n_headings == 12
    assert p.arbiter.selection == 'episode' and p.learner.correction == 'paper'
    assert p.learner.resample == 'spline'
    assert p.innate.value.v_init > p.view.value.v_init


def test_config_file_is_a_ros_parameter_file_with_every_value_commented():
    path = config_dir() / 'clis.yaml'
    params = ros_parameters(path, node='/**')
    assert set(params) == {'common', 'modules', 'innate', 'view', 'place', 'wall', 'arbiter',
                           'learner'}
    assert params['modules'] == ['innate', 'view', 'place', 'wall']
    for line in path.read_text().splitlines():
        s = line.strip()
        if s and not s.startswith('#') and not s.endswith(':') and ':' in s:
            assert '#' in s, f'value without a comment (units, source): {line!r}'


def test_overrides_nested_and_dotted():
    p = load_clis_params(overrides={'common.beta': 200.0, 'view': {'policy': {'sigma': 0.2}}})
    assert p.common.beta == 200.0 and p.view.policy.sigma == 0.2
    assert params_hash(p) != params_hash(load_clis_params())
    assert params_hash(load_clis_params()) == params_hash(load_clis_params())


@pytest.mark.parametrize('key,value,match', [
    ('common.beta', -1.0, 'common.beta'),
    ('common.gamma', 1.5, 'common.gamma'),
    ('innate.n_rbf', 0, 'innate.n_rbf'),
    ('place.localization.cell_size', 0.0, 'place.localization.cell_size'),
    ('learner.resample', 'linear', 'learner.resample'),
    ('arbiter.selection', 'always', 'arbiter.selection'),
    ('view.policy.learn_sigma', 'yes', 'view.policy.learn_sigma'),
    ('view.policy.sigma', 0.9, 'sigma_min <= sigma <= sigma_max'),
    ('common.nope', 1.0, 'common.nope'),
])
def test_bad_values_name_the_key(key, value, match):
    with pytest.raises(ConfigError, match=match.replace('.', r'\.')):
        load_clis_params(overrides={key: value})


def test_missing_key_is_reported(tmp_path):
    data = yaml.safe_load((config_dir() / 'clis.yaml').read_text())
    del data['/**']['ros__parameters']['learner']['lambda_']
    path = tmp_path / 'clis.yaml'
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError, match=r'learner\.lambda_'):
        load_clis_params(path)


# ------------------------------------------------------------------------------ checkpoints

@pytest.fixture
def modules():
    """Async modules with non-trivial parameters."""
    mods = make_modules(load_clis_params(), 'async', LANDMARKS, 1.5)
    rng = np.random.default_rng(0)
    for m in mods:
        m.w = rng.normal(size=m.n)
        m.W = rng.normal(size=(2, m.n))
        m.sigma = 0.123
    return mods


def fresh():
    return make_modules(load_clis_params(), 'async', LANDMARKS, 1.5)


def test_checkpoint_round_trip(tmp_path, modules):
    path = tmp_path / 'ckpt.npz'
    save_checkpoint(path, modules, params_hash='abc', metadata={'episode': 17})
    other = fresh()
    meta = load_checkpoint(path, other, params_hash='abc')
    assert meta['extra'] == {'episode': 17} and meta['params_hash'] == 'abc'
    assert [d['name'] for d in meta['modules']] == ['innate', 'view', 'place']
    for a, b in zip(modules, other):
        assert np.array_equal(a.w, b.w) and np.array_equal(a.W, b.W) and a.sigma == b.sigma
    assert sorted(os.listdir(tmp_path)) == ['ckpt.npz']                # no temp file left


def test_checkpoint_validates_before_assigning(tmp_path, modules):
    path = tmp_path / 'ckpt.npz'
    save_checkpoint(path, modules, params_hash='abc')
    with pytest.raises(CheckpointError, match='expected'):
        load_checkpoint(path, fresh(), params_hash='xyz')
    small = make_modules(load_clis_params(overrides={'view.n_dist': 5}), 'async', LANDMARKS, 1.5)
    before = small[0].w.copy()
    with pytest.raises(CheckpointError, match=r'view\.w has shape'):
        load_checkpoint(path, small)
    assert np.array_equal(small[0].w, before)            # innate came first: still untouched
    with pytest.raises(CheckpointError, match='no such'):
        load_checkpoint(tmp_path / 'none.npz', fresh())
    (tmp_path / 'junk.npz').write_bytes(b'not a zip')
    with pytest.raises(CheckpointError, match='not a readable'):
        load_checkpoint(tmp_path / 'junk.npz', fresh())


def test_interrupted_write_keeps_the_old_checkpoint(tmp_path, modules, monkeypatch):
    path = tmp_path / 'ckpt.npz'
    save_checkpoint(path, modules, metadata={'episode': 1})
    old_bytes = path.read_bytes()

    def crash(fh, arrays):
        fh.write(b'PK\x03\x04 half a zip')               # partial output, then the crash
        raise KeyboardInterrupt('killed mid-write')

    monkeypatch.setattr(ckpt, '_savez', crash)
    for m in modules:
        m.w = np.zeros(m.n)
    with pytest.raises(KeyboardInterrupt):
        save_checkpoint(path, modules, metadata={'episode': 2})
    monkeypatch.undo()
    assert path.read_bytes() == old_bytes
    assert sorted(os.listdir(tmp_path)) == ['ckpt.npz']
    assert load_checkpoint(path, fresh())['extra'] == {'episode': 1}


def test_crash_before_rename_keeps_the_old_checkpoint(tmp_path, modules, monkeypatch):
    path = tmp_path / 'ckpt.npz'
    save_checkpoint(path, modules, metadata={'episode': 1})

    def no_replace(src, dst):
        raise OSError('disk full')

    monkeypatch.setattr(ckpt.os, 'replace', no_replace)
    with pytest.raises(OSError):
        save_checkpoint(path, modules, metadata={'episode': 2})
    monkeypatch.undo()
    assert load_checkpoint(path, fresh())['extra'] == {'episode': 1}
    assert [Path(f).name for f in os.listdir(tmp_path)] == ['ckpt.npz']
