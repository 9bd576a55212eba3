"""Modules as plug-ins (clis_modules.core.plugin, docs/modules.md): the registry (one list,
with or without the package's metadata), the feature models and their hooks, conditions as sets
of modules, module instances in the config file (partial sections merged over their plug-in's
defaults), the wall module, every sensor in the percept, and the graph plan of any set of
modules."""

from __future__ import annotations

import copy
import dataclasses
import importlib.resources
import json
import math
import os
from pathlib import Path
import shutil
import subprocess
import sys

from clis_app.experiments.runner import Agent, JobSpec, run_episode, run_job
from clis_base.params import ConfigError, config_dir, load_yaml
from clis_learner.core.config import load_clis_params
from clis_modules.core import plugin as plugin_api
from clis_modules.core.modules import (
    arena_map,
    condition_periods,
    condition_sensors,
    make_modules,
)
from clis_modules.core.plugin import (
    ENTRY_POINT_GROUP,
    HOOKS,
    OWN_ENTRY_POINTS,
    FeatureModel,
    Floor,
    ModulePlugin,
    Percept,
    get_plugin,
    parse_condition,
    plugins,
    read_entry_points,
)
from cr_sim.core.arena import load_arena
from cr_sim.core.sim import Simulator, load_sim_params
import numpy as np
import pytest
import yaml

# results pinned bit for bit: tools/cpu_check.py runs these under each CPU kernel set
pytestmark = pytest.mark.bits

LANDMARKS = np.array([[1.5, 0.75], [-0.75, 1.5], [-1.5, -0.75], [0.75, -1.5]])
FLOOR = Floor.square(1.5)


def test_the_project_registers_its_four_plugins_under_the_group():
    from importlib.metadata import entry_points
    names = {ep.name for ep in entry_points(group=ENTRY_POINT_GROUP)}
    assert {'innate', 'view', 'place', 'wall'} <= names
    assert {'innate', 'view', 'place', 'wall'} <= set(plugins())
    for name in ('innate', 'view', 'place', 'wall'):
        p = get_plugin(name)
        assert isinstance(p, ModulePlugin) and p.name == name
    assert get_plugin('innate').learned is False and get_plugin('wall').learned is True
    assert get_plugin('innate').sensors == ('camera',)
    assert 'wheels' in get_plugin('place').sensors
    with pytest.raises(ValueError, match='no module plug-in'):
        get_plugin('nosuch')


def _own_entry_points() -> dict[str, str]:
    package, filename = OWN_ENTRY_POINTS
    text = importlib.resources.files(package).joinpath(filename).read_text(encoding='utf-8')
    return read_entry_points(text)[ENTRY_POINT_GROUP]


def test_the_installed_entry_points_are_the_packages_one_list():
    """setup.py registers the file's entry points: the metadata (the colcon install's) holds
    exactly those of clis_modules."""
    from importlib.metadata import entry_points
    installed = {ep.name: ep.value for ep in entry_points(group=ENTRY_POINT_GROUP)
                 if ep.dist is not None and ep.dist.name.replace('-', '_') == 'clis_modules'}
    own = _own_entry_points()
    assert set(own) == {'innate', 'view', 'place', 'wall'}
    assert installed == own
    assert not hasattr(plugin_api, '_BUILTIN')


def test_without_the_packages_metadata_the_same_plugins_are_found(tmp_path):
    """A source tree on PYTHONPATH alone (tools/rules_digest.py --at: a commit's code from git
    archive) finds the package's plug-ins in the file that setup.py reads."""
    src = Path(__file__).resolve().parent.parent / 'src'
    code = ('import json; from importlib.metadata import distribution, PackageNotFoundError\n'
            'try:\n    distribution("clis_modules"); found = True\n'
            'except PackageNotFoundError:\n    found = False\n'
            'from clis_modules.core.plugin import plugins, get_plugin\n'
            'print(json.dumps([found, plugins(), type(get_plugin("place")).__name__]))')
    env = {'PATH': os.environ.get('PATH', ''), 'HOME': str(tmp_path),
           'PYTHONPATH': os.pathsep.join(str(src / p)
                                         for p in ('clis_base', 'cr_sim', 'clis_modules'))}
    out = subprocess.run([sys.executable, '-S', '-c', code], capture_output=True, text=True,
                         env=env, cwd=tmp_path, timeout=120)
    if out.returncode != 0 and 'numpy' in out.stderr:
        # -S left out the venv's site-packages: only the install's metadata must go
        site = [p for p in sys.path if p.endswith('site-packages') and '/install/' not in p]
        env['PYTHONPATH'] += os.pathsep + os.pathsep.join(site)
        out = subprocess.run([sys.executable, '-S', '-c', code], capture_output=True,
                             text=True, env=env, cwd=tmp_path, timeout=120)
    assert out.returncode == 0, out.stderr
    found, registry, place = json.loads(out.stdout)
    assert not found                                    # no metadata of clis_modules here
    # the venv's site-packages may hold another package's plug-ins (test_plugin_package
    # installs one while this runs): the package's own are all there, as the file says
    own = _own_entry_points()
    assert {k: registry.get(k) for k in own} == own and place == 'Place'


class _Stateless(FeatureModel):
    def features(self, percept: Percept) -> np.ndarray:
        return np.array([1.0])


def test_a_feature_model_overrides_the_hooks_it_needs():
    assert set(HOOKS) == {'reset', 'motion', 'sense', 'peek', 'at_pose', 'display'}
    assert not any(_Stateless.has(h) for h in HOOKS)
    m = _Stateless(1)
    m.reset(), m.motion(0.1, 0.0, 0.0), m.sense(None), m.at_pose(0.0, 0.0, 0.0)
    assert m.display() is None and m.peek(None, None).tolist() == [1.0]
    assert (m.n, m.W, m.sigma, m.sigma_blind, m.state) == (1, None, None, None, None)
    with pytest.raises(ValueError, match='no hook'):
        m.has('features')
    with pytest.raises(NotImplementedError):
        FeatureModel(1).features(None)
    view, place = make_modules(load_clis_params(), 'async:view+place', LANDMARKS, FLOOR)
    assert all(place.model.has(h) for h in HOOKS)
    # the framework calls only the hooks a model has: none of the view module's
    assert (view.on_motion, view.on_sense, view.peek_fn, view.at_pose, view.display) == (
        None, None, None, None, None)
    assert place.on_motion.__self__ is place.model and place.state is place.model.loc


def test_a_copied_module_has_its_own_state_shared_by_its_hooks():
    """copy.deepcopy (a module node's warm-up) copies the model, its state and its hooks
    together: the copy's hooks change the copy's state, the original is left as it was."""
    (place,) = make_modules(load_clis_params(), 'place', LANDMARKS, FLOOR)
    before = place.state.belief.copy()
    twin = copy.deepcopy(place)
    assert twin.model is not place.model and twin.state is twin.model.loc
    for hook in (twin.on_motion, twin.on_sense, twin.peek_fn, twin.at_pose, twin.display,
                 twin.feature_fn):
        assert hook.__self__ is twin.model
    twin.at_pose(0.5, -0.5, 0.3)
    assert twin.state.belief.max() == 1.0 and twin.features(0.0)[np.argmax(
        twin.state.belief)] == 1.0
    np.testing.assert_array_equal(place.state.belief, before)


def test_the_modules_see_the_arena_floor_as_a_named_rectangle():
    from cr_sim.core.arena import load_arena
    arena = load_arena(None)
    landmarks, floor, boxes = arena_map(arena)
    assert floor == Floor(*arena.bounds) and floor.half == 1.5 == arena.half
    assert Floor(-1.0, 0.0, 2.0, 1.0).half is None
    with pytest.raises(ValueError, match='xmin < xmax'):
        Floor(1.0, 0.0, 0.0, 1.0)
    seen = []

    class Probe(ModulePlugin):
        Params = get_plugin('view').Params

        def model(self, prm, ctx):
            seen.append(ctx.floor)
            return _Stateless(1)
    from clis_modules.core.modules import build_module
    params = load_clis_params()
    build_module('probe', Probe(), params.view, params.common, None, landmarks, floor, boxes)
    build_module('probe', Probe(), params.view, params.common, None, landmarks, 1.5, boxes)
    assert seen == [floor, Floor.square(1.5)]


@pytest.mark.parametrize('text, timing, modules', [
    ('innate', 'async', ('innate',)), ('place', 'async', ('place',)),
    ('sync', 'sync', ('innate', 'view', 'place')), ('async', 'async', ('innate', 'view', 'place')),
    ('async:innate+view+place+wall', 'async', ('innate', 'view', 'place', 'wall')),
    ('sync:innate+view', 'sync', ('innate', 'view')), ('async:wall', 'async', ('wall',)),
])
def test_conditions_parse_in_one_place(text, timing, modules):
    c = parse_condition(text)
    assert (c.timing, c.modules) == (timing, modules)


@pytest.mark.parametrize('text', ['both', 'async:', 'fast:innate', 'async:innate+innate',
                                  'async:innate+', 'innate+view'])
def test_bad_conditions_say_the_form(text):
    with pytest.raises(ValueError, match='condition'):
        parse_condition(text)


def test_paper_names_are_their_sets_of_modules():
    params = load_clis_params()
    assert condition_periods(params, 'async') == condition_periods(
        params, 'async:innate+view+place') == [('innate', 0.25), ('view', 0.5), ('place', 1.2)]
    assert condition_periods(params, 'sync') == [(m, 1.2) for m in ('innate', 'view', 'place')]
    assert condition_periods(params, 'sync:innate+view') == [('innate', 0.5), ('view', 0.5)]
    assert condition_periods(params, 'async:innate+wall') == [('innate', 0.25), ('wall', 0.75)]
    with pytest.raises(ValueError, match="unknown module 'nosuch'"):
        condition_periods(params, 'async:innate+nosuch')
    assert condition_sensors(params, 'async:innate+place') == {
        'innate': ('camera',), 'place': ('camera', 'wheels')}


def _config(tmp_path: Path, edit) -> Path:
    data = load_yaml(config_dir() / 'clis.yaml')
    edit(data['/**']['ros__parameters'])
    path = tmp_path / 'clis.yaml'
    path.write_text(yaml.safe_dump(data))
    return path


def _view_fast(p):
    """A second instance of the view plug-in, given by the key that differs alone."""
    p['modules'] = [*p['modules'], 'view_fast']
    p['view_fast'] = {'plugin': 'view', 'period': 0.25}


def test_two_instances_of_one_plugin_run_side_by_side(tmp_path):
    params = load_clis_params(_config(tmp_path, _view_fast))
    assert params.view_fast == dataclasses.replace(params.view, period=0.25)
    mods = make_modules(params, 'async:view+view_fast', LANDMARKS, FLOOR)
    assert [(m.name, m.plugin, m.period) for m in mods] == [('view', 'view', 0.5),
                                                            ('view_fast', 'view', 0.25)]
    assert mods[0].v_max < mods[1].v_max                   # the speed limit of its period
    arena = load_arena(None)
    sim_params = load_sim_params(overrides={'episode.time_limit': 5.0})
    sim = Simulator(arena, sim_params, np.random.default_rng(0))
    agent = Agent(params, 'async:view+view_fast', arena, np.random.default_rng(1),
                  sim_params.robot.wheel_base)
    row = run_episode(sim, agent, 'A', None)
    assert {'share_view', 'share_view_fast'} <= set(row)


def test_a_partial_section_is_merged_key_by_key_and_checked(tmp_path):
    def edit(p):
        _view_fast(p)
        p['view_fast']['policy'] = {'sigma': 0.2}
        p['view']['n_dist'] = 5                           # the configuration's view section
    params = load_clis_params(_config(tmp_path, edit))
    assert params.view_fast == dataclasses.replace(
        params.view, period=0.25, policy=dataclasses.replace(params.view.policy, sigma=0.2))
    assert params.view_fast.n_dist == 5
    for bad, says in (({'perod': 0.25}, r'unknown key view_fast\.perod; did you mean '
                                        r'view_fast\.period\?'),
                      ({'policy': {'sigam': 0.2}}, r'unknown key view_fast\.policy\.sigam; '
                                                   r'did you mean view_fast\.policy\.sigma\?'),
                      ({'period': -1.0}, r'view_fast\.period = -1\.0 is out of range')):
        def edit(p, bad=bad):
            _view_fast(p)
            p['view_fast'] = {'plugin': 'view', **bad}
        with pytest.raises(ConfigError, match=says):
            load_clis_params(_config(tmp_path, edit))


class _Demo(ModulePlugin):
    """A plug-in with defaults (as a user's package would declare it)."""

    Params = get_plugin('wall').Params
    defaults = {'period': 0.3, 'n_rays': 7, 'n_dist': 2, 'phi_dist': 0.01, 'd_max': 0.5,
                'n_theta': 3, 'phi_theta': 0.5, 'value': {'alpha': 0.1, 'v_init': 0.0},
                'policy': {'alpha': 0.1, 'sigma': 0.1, 'learn_sigma': False, 'sigma_min': 0.02,
                           'sigma_max': 0.5, 'alpha_sigma': 0.0}}


def test_a_section_is_merged_over_its_plugins_defaults(tmp_path, monkeypatch):
    plugins()
    monkeypatch.setitem(plugin_api._FOUND, 'demo', 'test_plugins:_Demo')
    monkeypatch.setitem(plugin_api._CACHE, 'demo', _Demo())
    plugin_api._CACHE['demo'].name = 'demo'

    def edit(p):
        p['modules'] = [*p['modules'], 'demo', 'demo_slow']
        p['demo'] = {'n_theta': 5}
        p['demo_slow'] = {'plugin': 'demo', 'period': 0.9}
    params = load_clis_params(_config(tmp_path, edit))
    assert (params.demo.period, params.demo.n_theta, params.demo.n_dist) == (0.3, 5, 2)
    assert (params.demo_slow.period, params.demo_slow.n_theta) == (0.9, 5)
    assert params.module('demo_slow')[0] is plugin_api._CACHE['demo']


def test_a_second_instance_given_by_its_period_alone_runs_an_experiment(tmp_path, monkeypatch):
    """The acceptance run: a config folder whose clis.yaml adds ``view_fast: {plugin: view,
    period: 0.25}`` alone, and a headless job of async:innate+view+view_fast (2 episodes)."""
    conf = tmp_path / 'config'
    shutil.copytree(config_dir(), conf)
    data = load_yaml(config_dir() / 'clis.yaml')
    _view_fast(data['/**']['ros__parameters'])
    (conf / 'clis.yaml').write_text(yaml.safe_dump(data))
    monkeypatch.setenv('CLIS_CONFIG_DIR', str(conf))
    spec = JobSpec(index=0, label='async:innate+view+view_fast',
                   condition='async:innate+view+view_fast', overrides={},
                   sim_overrides={'episode.time_limit': 10.0}, seed=0, episodes=2,
                   eval_episodes=1, arena=None, run_dir=str(tmp_path / 'runs'), block=2)
    spec.validate()
    (tmp_path / 'runs').mkdir()
    result = run_job(spec)
    assert result.modules == ['innate', 'view', 'view_fast']
    assert len(result.episodes) == 2
    assert {'share_view_fast', 'p_view_fast'} <= set(result.episodes[0])
    ckpt = np.load(spec.result_path().with_suffix('.npz'))
    assert ckpt['view_fast.W'].shape == ckpt['view.W'].shape


def test_a_missing_section_of_an_unused_module_is_not_an_error(tmp_path):
    def edit(p):
        del p['place']
        p['modules'] = ['innate', 'view', 'wall']
    params = load_clis_params(_config(tmp_path, edit))
    assert [m.name for m in make_modules(params, 'sync:innate+view', LANDMARKS, FLOOR)] == [
        'innate', 'view']
    with pytest.raises(ConfigError, match='no section place'):
        make_modules(params, 'async', LANDMARKS, FLOOR)


@pytest.mark.parametrize('edit, says', [
    (lambda p: p['wall'].update(period=-1.0), r'wall\.period = -1\.0 is out of range: must be '
                                              r'in \[0\.01, 60\.0\]'),
    (lambda p: p.update(walll=p['wall']), 'unknown key walll; allowed keys'),
    (lambda p: p['wall'].update(plugin='nosuch'), r"wall\.plugin: no module plug-in 'nosuch'"),
    (lambda p: p['view'].update(n_dist=0), r'view\.n_dist = 0 is out of range'),
])
def test_bad_instance_sections_name_the_key_and_range(tmp_path, edit, says):
    with pytest.raises(ConfigError, match=says):
        load_clis_params(_config(tmp_path, edit))


def test_wall_features_read_every_ir_ray_and_the_bearing():
    wall = make_modules(load_clis_params(), 'async:wall', LANDMARKS, FLOOR)[0]
    assert (wall.period, wall.learned, wall.n) == (0.75, True, 7 * 4 + 9 + 1)
    lm = np.full(4, math.nan)
    free = Percept(0.0, 0.3, 0.5, lm, np.full(7, 0.5))
    left = Percept(0.0, 0.3, 0.05, lm, np.array([0.05, 0.5, 0.5, 0.5, 0.5, 0.5, 0.5]))
    right = Percept(0.0, 0.3, 0.05, lm, np.array([0.5, 0.5, 0.5, 0.5, 0.5, 0.5, 0.05]))
    b = [wall.features(p) for p in (free, left, right)]
    for x in b:
        assert x.shape == (wall.n,) and x.sum() == pytest.approx(1.0)
    assert not np.allclose(b[1], b[2])                     # where the obstacle is, not only d_o
    np.testing.assert_array_equal(b[0][28:], b[1][28:])    # the same bearing block
    blind = wall.features(Percept(0.0, math.nan, 0.5, lm, np.full(7, 0.5)))
    assert blind[-1] == pytest.approx(1.0 / 8)             # the not-visible feature


def test_the_percept_carries_every_sensor_as_the_observation_has_it():
    arena = load_arena(None)
    sim = Simulator(arena, load_sim_params(), np.random.default_rng(4))
    sim.reset('A')
    sim.step(np.array([0.2, 0.3]))
    dest, d_o, lm, ir, wheels = sim.sense_all()
    obs = sim.observe()
    assert (dest, d_o) == (sim.sense()[0], sim.sense()[1]) == (obs.dest_bearing, obs.d_o)
    np.testing.assert_array_equal(ir, obs.ir)
    np.testing.assert_array_equal(wheels, obs.wheels)
    np.testing.assert_array_equal(lm, obs.landmark_bearings)
    assert ir.shape == (7,) and d_o == ir.min()
    p = Percept.from_observation(obs.t, obs)
    np.testing.assert_array_equal(p.ir, obs.ir)


def test_graph_plan_starts_any_module_as_the_generic_node(tmp_path):
    from clis_app.graph.plan import plan_graph
    plan = plan_graph('async:innate+wall', 0, tmp_path, 0.0)
    wall = plan.by_name('wall')
    assert (wall.package, wall.executable, wall.remaps) == ('clis_modules', 'module',
                                                            {'__node': 'wall'})
    sim = plan.by_name('sim')
    assert 'camera:2' in sim.params['node.start_subscribers']
    assert sim.params['node.lockstep_periods'] == [0.25, 0.75]
    assert sim.params['node.command'] == 'wheels_cmd'       # the arbiter's wheels, exact


def test_graph_plan_takes_the_periods_of_the_params_files(tmp_path):
    """The nodes read ``--params``; the simulator's lockstep instants must be those too (they
    came from config/clis.yaml alone: a period override deadlocked the lockstep at instants no
    module decided on). The agent stream is not the simulator's: the learner, which reads the
    same files, keeps it (clis_learner.core.agent_state)."""
    from clis_app.graph.plan import plan_graph
    sim = plan_graph('async:innate+wall', 0, tmp_path, 0.0, clis_overrides={
        'wall.period': 1.0, 'arbiter.selection': 'decision'}).by_name('sim')
    assert sim.params['node.lockstep_periods'] == [0.25, 1.0]
    assert not any('agent' in key for key in sim.params)


def test_the_recorded_topics_are_those_of_the_conditions_modules():
    """The recorder subscribes from its start to the topics of its condition's modules (and
    the live view serves them): every instance's, none of another condition's."""
    from clis_app.bags.recorder_node import (
        GRAPH_TOPICS,
        LATCHED_TOPICS,
        graph_topics,
        latched_topics,
    )
    params = load_clis_params()
    assert not any(t.split('/')[0] in ('innate', 'view', 'place', 'wall') for t in GRAPH_TOPICS)
    four = graph_topics('async:innate+view+place+wall', params)
    for m in ('innate', 'view', 'place', 'wall'):
        for kind in ('proposal', 'params', 'observation'):
            assert four[f'{m}/{kind}'] == 'sensor_msgs/msg/JointState', (m, kind)
    assert four['place/belief'] == 'nav_msgs/msg/OccupancyGrid'
    assert set(graph_topics('view', params)) - set(GRAPH_TOPICS) == {'view/proposal',
                                                                     'view/params'}
    assert latched_topics('async:innate+wall') == LATCHED_TOPICS | {'innate/params',
                                                                     'wall/params'}
