"""The shape of the code: no import cycles, pure cores, one-way layers from the application down
to clis_base, a simulator without agent concepts, and rclpy's private API in one place."""

from __future__ import annotations

import ast
import importlib.util
from pathlib import Path
import re

REPO = Path(__file__).resolve().parent.parent
SRC = REPO / 'src'


def _tool():
    spec = importlib.util.spec_from_file_location(
        'check_import_cycles', REPO / 'tools' / 'check_import_cycles.py')
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_no_import_cycles():
    """Every import counts, function-local ones too (tools/check_import_cycles.py)."""
    assert _tool().import_cycles(SRC) == []


def test_the_cycle_check_finds_a_cycle_hidden_in_a_function(tmp_path):
    pkg = tmp_path / 'src' / 'pkg' / 'pkg'
    pkg.mkdir(parents=True)
    (pkg / '__init__.py').write_text('')
    (pkg / 'a.py').write_text('from pkg.b import f\n')
    (pkg / 'b.py').write_text('def f():\n    from pkg import a\n    return a\n')
    (pkg / 'c.py').write_text('from . import a\n')
    assert _tool().import_cycles(tmp_path / 'src') == [['pkg.a', 'pkg.b']]


def _imports(path: Path) -> set[str]:
    names = set()
    for node in ast.walk(ast.parse(path.read_text(encoding='utf-8'))):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and not node.level:
            names.add(node.module)
    return names


#: The pure modules: every package's ``core/``, and clis_base's own (not its ``ros/``).
def pure_modules(src: Path) -> list[Path]:
    return sorted([*src.glob('*/*/core/*.py'), *src.glob('clis_base/clis_base/*.py')])


def test_the_cores_import_no_ros():
    """Every package's math is in its ``core/`` subpackage, without rclpy nor messages."""
    ros = re.compile(r'^(rclpy|rcl_interfaces|\w+_msgs|std_srvs|ament_index_python)\b')
    cores = pure_modules(SRC)
    assert cores
    for path in cores:
        bad = sorted(n for n in _imports(path) if ros.match(n))
        if path.name == 'params.py':        # config_dir's fallback to the installed share/
            bad = [n for n in bad if n != 'ament_index_python.packages']
        assert not bad, f'{path.relative_to(REPO)} imports {bad}'


#: rclpy's private members the project uses (as attributes or by name), and its C extension.
PRIVATE = re.compile(r'\b_parameter_overrides\b|\b_time_source\b|\b_callback_type\b'
                     r'|\b_sigint_gc\b|\b_tasks_lock\b|\._tasks\b|\b_is_shutdown\b'
                     r'|\b_spin_once_impl\b|implementation_singleton|executors\._rclpy'
                     r'|\._take_(waitable|client|service)\b|\._guard\b|\._context\b')


def test_rclpys_private_members_are_used_in_one_module_only():
    adapter = SRC / 'clis_base' / 'clis_base' / 'ros' / 'rclpy_private.py'
    assert PRIVATE.search(adapter.read_text(encoding='utf-8'))
    for path in sorted(SRC.rglob('*.py')):
        if path == adapter:
            continue
        for k, line in enumerate(path.read_text(encoding='utf-8').splitlines(), 1):
            code = line.split('#', 1)[0]
            assert not PRIVATE.search(code), \
                f'{path.relative_to(REPO)}:{k}: rclpy private API outside rclpy_private: {line}'


def test_the_robots_body_is_read_from_robot_yaml_only():
    """The body (radius, wheel base, wheel limit) is described once: config/robot.yaml."""
    import yaml
    for name in ('sim.yaml', 'bridge.yaml', 'graph.yaml', 'clis.yaml'):
        data = yaml.safe_load((REPO / 'config' / name).read_text(encoding='utf-8'))
        for section in data.values():
            assert 'robot' not in section['ros__parameters'], f'config/{name} has a robot section'
    for path in sorted(SRC.rglob('*.py')):
        text = path.read_text(encoding='utf-8')
        assert not re.search(r"ros_parameters\([^)]*sim\.yaml[^)]*\)\[\s*'robot'", text), path



#: The packages in the order their imports may run: each imports only those before it.
LAYERS = ('clis_base', 'cr_sim', 'cr_bridge', 'clis_modules', 'clis_learner', 'clis_app')
#: What belongs to the agent (the modules, the arbiter, the learner, the runner): the simulator
#: imports none of it.
AGENT_CONCEPTS = ('clis_base.agent_stream',)
#: cr_bridge and clis_modules are side by side: neither imports the other.
SIDE_BY_SIDE = {('cr_bridge', 'clis_modules'), ('clis_modules', 'cr_bridge')}


def upward_imports(src: Path) -> list[str]:
    """``FILE imports [PKG]`` for every import against the layers (function-local ones too)."""
    bad = []
    for k, package in enumerate(LAYERS):
        for path in sorted((src / package / package).rglob('*.py')):
            tops = {name.split('.')[0] for name in _imports(path)} & set(LAYERS) - {package}
            wrong = sorted(t for t in tops
                           if t in LAYERS[k + 1:] or (package, t) in SIDE_BY_SIDE)
            if wrong:
                bad.append(f'{path.relative_to(src)} imports {wrong}')
    return bad


def node_plumbing_in_cores(src: Path) -> list[str]:
    """``FILE imports [MODULE]`` for a pure module importing node plumbing (``clis_base.ros``)."""
    return [f'{path.relative_to(src)} imports {bad}' for path in pure_modules(src)
            if (bad := sorted(n for n in _imports(path)
                              if n == 'clis_base.ros' or n.startswith('clis_base.ros.')))]


def agent_concepts_in_the_simulator(src: Path) -> list[str]:
    """``FILE imports [MODULE]`` for a simulator module importing an agent concept."""
    return [f'{path.relative_to(src)} imports {bad}'
            for path in sorted((src / 'cr_sim' / 'cr_sim').rglob('*.py'))
            if (bad := sorted(n for n in _imports(path)
                              if any(n == a or n.startswith(a + '.') for a in AGENT_CONCEPTS)))]


def test_the_simulator_imports_no_agent_concept_and_the_cores_no_node_plumbing():
    """The simulator package holds the simulator (the agent's stream is the learner's to keep,
    clis_learner.core.agent_state); the pure cores import none of clis_base.ros."""
    assert agent_concepts_in_the_simulator(SRC) == []
    assert node_plumbing_in_cores(SRC) == []


def test_the_floor_checks_find_what_they_look_for(tmp_path):
    (tmp_path / 'cr_sim' / 'cr_sim' / 'core').mkdir(parents=True)
    (tmp_path / 'clis_base' / 'clis_base').mkdir(parents=True)
    (tmp_path / 'cr_sim' / 'cr_sim' / 'sim_node.py').write_text(
        'def f():\n    from clis_base.agent_stream import AgentStream\n    return AgentStream\n')
    (tmp_path / 'cr_sim' / 'cr_sim' / 'core' / 'sim.py').write_text(
        'from clis_base.ros.process import realtime\n')
    (tmp_path / 'clis_base' / 'clis_base' / 'params.py').write_text('import clis_base.ros\n')
    assert agent_concepts_in_the_simulator(tmp_path) == [
        "cr_sim/cr_sim/sim_node.py imports ['clis_base.agent_stream']"]
    assert node_plumbing_in_cores(tmp_path) == [
        "clis_base/clis_base/params.py imports ['clis_base.ros']",
        "cr_sim/cr_sim/core/sim.py imports ['clis_base.ros.process']"]


def test_imports_run_one_way_from_the_application_to_the_simulator():
    """The learning package imports nothing of the application; no package imports upwards."""
    assert sorted(p.name for p in SRC.iterdir() if (p / 'package.xml').exists()) \
        == sorted(LAYERS)
    assert upward_imports(SRC) == []


def test_the_one_way_check_finds_an_upward_import(tmp_path):
    """A learner module that imports the application in a function is found."""
    for package in LAYERS:
        (tmp_path / package / package).mkdir(parents=True)
    (tmp_path / 'clis_learner' / 'clis_learner' / 'memory.py').write_text(
        'def f():\n    from clis_app.core import runner\n    return runner\n')
    (tmp_path / 'cr_bridge' / 'cr_bridge' / 'a.py').write_text('import clis_modules.core\n')
    (tmp_path / 'clis_app' / 'clis_app' / 'b.py').write_text('import cr_sim, clis_learner\n')
    assert upward_imports(tmp_path) == [
        "cr_bridge/cr_bridge/a.py imports ['clis_modules']",
        "clis_learner/clis_learner/memory.py imports ['clis_app']"]


def test_the_learning_package_has_no_plotting_dependency():
    xml = (SRC / 'clis_learner' / 'package.xml').read_text(encoding='utf-8')
    assert not re.search(r'matplotlib|plot', xml, re.IGNORECASE)
    setup = (SRC / 'clis_learner' / 'setup.py').read_text(encoding='utf-8')
    assert 'clis =' not in setup and 'recorder' not in setup
