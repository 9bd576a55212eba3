"""Modules as plug-ins (clis_modules.core.plugin, docs/modules.md): the registry, conditions as
sets of modules, module instances in the config file, the wall module, every sensor in the
percept, and the graph plan of any set of modules."""

from __future__ import annotations

import math
from pathlib import Path

from clis_app.core.runner import Agent, run_episode
from clis_learner.core.config import load_clis_params
from clis_modules.core.modules import condition_periods, condition_sensors, make_modules
from clis_modules.core.plugin import (
    ENTRY_POINT_GROUP,
    ModulePlugin,
    Percept,
    get_plugin,
    parse_condition,
    plugins,
)
from cr_sim.core.arena import load_arena
from cr_sim.core.params import ConfigError, config_dir, load_yaml
from cr_sim.core.sim import Simulator, load_sim_params
import numpy as np
import pytest
import yaml

LANDMARKS = np.array([[1.5, 0.75], [-0.75, 1.5], [-1.5, -0.75], [0.75, -1.5]])


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


def test_two_instances_of_one_plugin_run_side_by_side(tmp_path):
    def edit(p):
        p['modules'] = [*p['modules'], 'view_fast']
        p['view_fast'] = {**p['view'], 'plugin': 'view', 'period': 0.25}
    params = load_clis_params(_config(tmp_path, edit))
    mods = make_modules(params, 'async:view+view_fast', LANDMARKS, 1.5)
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


def test_a_missing_section_of_an_unused_module_is_not_an_error(tmp_path):
    def edit(p):
        del p['place']
        p['modules'] = ['innate', 'view', 'wall']
    params = load_clis_params(_config(tmp_path, edit))
    assert [m.name for m in make_modules(params, 'sync:innate+view', LANDMARKS, 1.5)] == [
        'innate', 'view']
    with pytest.raises(ConfigError, match='no section place'):
        make_modules(params, 'async', LANDMARKS, 1.5)


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
    wall = make_modules(load_clis_params(), 'async:wall', LANDMARKS, 1.5)[0]
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
    from clis_app.graph_plan import plan_graph
    plan = plan_graph('async:innate+wall', 0, tmp_path, 0.0)
    wall = plan.by_name('wall')
    assert (wall.package, wall.executable, wall.remaps) == ('clis_modules', 'module',
                                                            {'__node': 'wall'})
    sim = plan.by_name('sim')
    assert 'camera:2' in sim.params['node.start_subscribers']
    assert sim.params['node.lockstep_periods'] == [0.25, 0.75]
    assert sim.params['node.command'] == 'wheels_cmd'       # the arbiter's wheels, exact


def test_graph_plan_takes_the_periods_and_selection_of_the_params_files(tmp_path):
    """The nodes read ``--params``; the simulator's lockstep instants and agent stream must
    be those too (they came from config/clis.yaml alone: a period override deadlocked the
    lockstep at instants no module decided on)."""
    from clis_app.graph_plan import plan_graph
    sim = plan_graph('async:innate+wall', 0, tmp_path, 0.0, clis_overrides={
        'wall.period': 1.0, 'arbiter.selection': 'decision'}).by_name('sim')
    assert sim.params['node.lockstep_periods'] == [0.25, 1.0]
    assert sim.params['node.agent_selection'] == 'decision'
