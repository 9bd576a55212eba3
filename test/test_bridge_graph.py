"""`clis run --robot bridge --device emulator`: the CLIS graph through the bridge."""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

from clis_app.graph import run as graph_cli
from clis_app.graph.plan import plan_graph
import pytest
from test_graph import clis_run, finish


def parse(*argv: str) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    graph_cli.register(p.add_subparsers())
    return p.parse_args(['run', *argv])


def test_plan_puts_the_emulator_and_the_bridge_in_place_of_the_simulator(tmp_path):
    plan = plan_graph('view', 3, tmp_path, 5.0, robot='bridge', device='emulator')
    assert [c.name for c in plan.children] == ['learner', 'arbiter', 'view', 'emulator',
                                               'bridge']
    emu, bridge = plan.children[-2:]
    link = emu.args[emu.args.index('--link') + 1]
    assert link.startswith('udp://127.0.0.1:') and bridge.params['node.device'] == link
    assert emu.args[emu.args.index('--speed') + 1] == '5.0'
    assert emu.argv([])[1:3] == ['--link', link], 'the emulator is not a ROS node'
    assert bridge.params['node.wait_for_learner'] and bridge.params['node.start'] == 'wander'
    real = plan_graph('view', 3, tmp_path, 1.0, robot='bridge', device='/dev/ttyUSB0')
    assert [c.name for c in real.children][-1] == 'bridge'
    assert 'emulator' not in [c.name for c in real.children]
    assert real.children[-1].params['node.device'] == '/dev/ttyUSB0'


def test_bridge_runs_on_real_time_and_only_the_emulator_runs_faster():
    args = parse('--robot', 'bridge')
    assert graph_cli._check_args(args) is None and args.speed == 1.0
    assert 'real time' in graph_cli._check_args(parse('--robot', 'bridge', '--device',
                                                      'udp://127.0.0.1:9750', '--speed', '5'))
    assert 'single-process' in graph_cli._check_args(parse('--robot', 'bridge',
                                                           '--single-process'))
    assert graph_cli._check_args(parse('--robot', 'bridge', '--speed', '8')) is None


@pytest.mark.ros
def test_clis_run_learns_through_the_bridge_and_the_emulator(tmp_path):
    out = tmp_path / 'run'
    code, text = finish(clis_run(out, '--robot', 'bridge', '--device', 'emulator',
                                 '--condition', 'innate', '--episodes', '3', '--speed', '10'),
                        300)
    assert code == 0, text
    with open(out / 'episodes.csv', newline='') as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) >= 3 and all(r['learned'] == '1' for r in rows[:3]), rows
    assert [int(r['episode']) for r in rows[:3]] == [1, 2, 3]
    assert all(r['start'] == 'wander' for r in rows)
    log = (out / 'logs' / 'bridge.log').read_text()
    assert 'connected to udp://127.0.0.1:' in log and 'Traceback' not in log
    assert Path(out / 'logs' / 'emulator.log').is_file()
    assert (out / 'checkpoint.npz').is_file() and (out / 'curve.csv').is_file()
