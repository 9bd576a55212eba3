"""What ``clis run --robot ros`` writes for a robot of another size (clis_app.graph.robot_ros):
the layout at the robot's size, read back as the arena the robot adapter scales itself, and the
modules' features sized with it."""

from __future__ import annotations

from dataclasses import replace

from clis_app.graph.robot_ros import robot_files
from clis_base.params import load_yaml
from clis_learner.core.config import load_clis_params
from cr_sim.core.arena import arena_data, load_arena, parse_arena, scaled_arena
from cr_sim.core.profile import load_profile
import numpy as np
import pytest


def test_an_arena_written_out_reads_back_the_same():
    arena = load_arena()
    assert replace(parse_arena(arena_data(arena), 0.11), source=arena.source) == arena
    big = scaled_arena(arena, 10.0 / 3.0)
    back = parse_arena(arena_data(big), 0.0)
    assert back.bounds == pytest.approx((-5.0, -5.0, 5.0, 5.0))
    assert back.destination.goal_radius == pytest.approx(0.5)
    assert [(m.x, m.y) for m in back.landmarks] == \
        [pytest.approx((m.x * 10 / 3, m.y * 10 / 3)) for m in arena.landmarks]


def test_the_husky_run_maps_the_arena_at_its_size(tmp_path):
    arena_file, params_file = robot_files('husky', tmp_path)
    profile = load_profile('husky')
    adapter = scaled_arena(load_arena(profile.arena.path(), robot_radius=0.0),
                           profile.arena.scale(3.0))
    mapped = load_arena(arena_file, robot_radius=0.0)
    assert mapped.bounds == pytest.approx(adapter.bounds)
    assert [(m.x, m.y) for m in mapped.landmarks] == \
        [pytest.approx((m.x, m.y)) for m in adapter.landmarks]
    keys = load_yaml(params_file)['/**']['ros__parameters']
    place = dict((n, p) for n, _, p in load_clis_params().instances)['place']
    assert keys['place']['localization']['cell_size'] == \
        pytest.approx(place.localization.cell_size * 10 / 3)
    assert keys['view']['d_max'] == profile.scan.range_max
    # the Cyber Rodent's own profile: nothing to write
    assert robot_files('cr', tmp_path / 'cr', write=False) == ('', None)
    assert not (tmp_path / 'cr').exists()


def test_the_plan_puts_a_waiting_robot_in_lockstep_with_the_condition_periods(tmp_path):
    """``clis run --robot ros``: our simulator (profile cr) always waits for the graph (its
    lockstep, its first tick once the detector and the adapter are matched), the adapter reads
    its frames in lockstep at the condition's decision periods; another robot only with
    ``--lockstep``; the detector's overlay only for a subscriber."""
    from clis_app.graph.plan import plan_graph
    from clis_modules.core.modules import condition_periods
    taus = [float(t) for _, t in condition_periods(load_clis_params(), 'async')]
    cr = {c.name: c for c in plan_graph('async', 0, tmp_path, 0.0, robot='ros',
                                         profile='cr').children}
    assert cr['sim'].params['node.lockstep'] is True
    # it waits out the adapter holding a frame for the learner (config/bridge.yaml's 30 s)
    assert cr['sim'].params['node.command_timeout'] == 30.0
    assert cr['sim'].params['node.start_subscribers'] == ['image_raw:1', 'ir:1', 'odom:1',
                                                          'cmd_vel:1']
    assert cr['robot'].params['node.lockstep'] is True
    assert cr['robot'].params['node.decision_periods'] == taus
    # its first episode once the graph has matched its interface: 3 modules, the arbiter
    # and the learner follow the episodes, view reads the IR, place the wheels, the learner
    # the rewards, the arbiter commands, the detector sends the camera
    assert cr['robot'].params['node.start_subscribers'] == [
        'episode:5', 'ir_ranges:1', 'wheels:1', 'reward:1', 'wheels_cmd:1', 'camera:1']
    assert cr['detector'].params['overlay'] is False
    for lockstep in (False, True):
        husky = {c.name: c for c in plan_graph('view', 0, tmp_path, 0.0, robot='ros',
                                                profile='husky', lockstep=lockstep).children}
        assert 'sim' not in husky and husky['robot'].params['node.lockstep'] is lockstep


def test_a_run_that_goes_on_numbers_the_robots_episodes_from_the_checkpoints(tmp_path):
    """``clis run --robot ros --resume`` (and ``--robot bridge``): the adapter (the bridge)
    numbers its first episode after the checkpoint's."""
    from clis_app.graph.plan import plan_graph
    for robot, name, extra in (('ros', 'robot', {'profile': 'husky'}),
                               ('bridge', 'bridge', {'device': 'udp://127.0.0.1:9'})):
        fresh = {c.name: c for c in plan_graph('view', 0, tmp_path, 1.0, robot=robot,
                                                **extra).children}
        on = {c.name: c for c in plan_graph('view', 0, tmp_path, 1.0, robot=robot,
                                             first_episode=41, **extra).children}
        assert 'node.first_episode' not in fresh[name].params
        assert on[name].params['node.first_episode'] == 41


def test_the_models_lengths_follow_the_robot_and_the_runs_preset():
    """On the Husky (10 m for the layout's 3 m: s = 10/3) the modules' speed limits, their
    exploration and the densities of (7) are the Cyber Rodent's at the robot's size: lengths
    and speeds times s, (7)'s epsilon over s^2, the speed cap the robot's own; the preset's
    values are the ones scaled; the Cyber Rodent's own profile changes nothing."""
    from clis_app.graph.robot_ros import robot_params
    from clis_base.params import flatten
    from clis_learner.core.config import preset_overrides
    s = 10.0 / 3.0
    for overrides in (None, preset_overrides('improved') | {'view.policy.sigma': 0.2}):
        base = load_clis_params(overrides=overrides)
        keys = robot_params('husky', overrides)
        robot = load_clis_params(overrides={**(overrides or {}), **flatten(keys)})
        inst = {n: p for n, _, p in base.instances}
        big = {n: p for n, _, p in robot.instances}
        assert robot.common.d_react == pytest.approx(base.common.d_react * s)
        assert robot.common.epsilon == pytest.approx(base.common.epsilon / s ** 2)
        assert robot.common.v_wheel_max == load_profile('husky').body.v_max
        for name in ('view', 'place', 'wall'):
            for key in ('sigma', 'sigma_min', 'sigma_max'):
                assert getattr(big[name].policy, key) == \
                    pytest.approx(getattr(inst[name].policy, key) * s)
        assert big['innate'].sigma == pytest.approx(inst['innate'].sigma * s)
        assert big['innate'].sigma_blind == pytest.approx(inst['innate'].sigma_blind * s)
        assert big['place'].features.phi_xy == pytest.approx(inst['place'].features.phi_xy
                                                              * s * s)
        assert big['view'].policy.sigma == pytest.approx((0.2 if overrides else 0.1) * s)
        # (7)'s ratio of two wheel densities (2-d Gaussians, std sigma) is the same at scale
        rng = np.random.default_rng(0)
        a, mu, mu2 = rng.normal(0.0, 0.2, (3, 2))
        sig = inst['view'].policy.sigma

        def pdf(scale: float, m: np.ndarray, a=a, sig=sig) -> float:
            d = scale * (a - m) / (scale * sig)
            return float(np.exp(-0.5 * d @ d) / (2 * np.pi * (scale * sig) ** 2))
        ratio = [(pdf(k, mu) + eps) / (pdf(k, mu2) + eps)
                 for k, eps in ((s, robot.common.epsilon), (1.0, base.common.epsilon))]
        assert ratio[0] == pytest.approx(ratio[1])
        # the Husky's forward camera splits view's not visible feature by side
        assert keys['view']['lost_side'] is True and big['view'].lost_side
    assert 'lost_side' not in robot_params('husky', {'view.lost_side': False}).get('view', {})
    assert robot_params('cr') == {}


def test_a_husky_run_goes_on_from_its_checkpoint(tmp_path):
    """``clis run --robot ros --profile husky --resume``: a checkpoint of the robot's own
    parameters (what its learner saved) is taken, one of the layout's size is refused."""
    from clis_app.cli import build_parser
    from clis_app.graph.robot_ros import robot_arena, robot_params
    from clis_app.graph.run import _check_args
    from clis_base.params import flatten
    from clis_learner.core.checkpoint import save_checkpoint
    from clis_learner.core.config import DEFAULT_PRESET, params_hash, preset_overrides
    from clis_modules.core.modules import arena_map, make_modules
    preset = preset_overrides(DEFAULT_PRESET)
    own = load_clis_params(overrides={**preset, **flatten(robot_params('husky', preset))})
    plain = load_clis_params(overrides=preset)
    for name, clis in (('own', own), ('plain', plain)):
        modules = make_modules(clis, 'view', *arena_map(robot_arena('husky')))
        save_checkpoint(tmp_path / f'{name}.npz', modules, params_hash(clis),
                        {'condition': 'view', 'seed': 0, 'episode': 7, 'version': 7})
    errors = {}
    for name in ('own', 'plain'):
        args = build_parser().parse_args(
            ['run', '--robot', 'ros', '--profile', 'husky', '--condition', 'view', '--resume',
             str(tmp_path / f'{name}.npz')])
        errors[name] = _check_args(args)
        if name == 'own':
            assert args.first_episode == 8
    assert errors['own'] is None
    assert 'cannot start from it' in errors['plain']
