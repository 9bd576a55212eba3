"""The shape of the code: no import cycles, pure cores, and rclpy's private API in one place."""

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


def test_the_cores_import_no_ros():
    """Every package's math is in its ``core/`` subpackage, without rclpy nor messages."""
    ros = re.compile(r'^(rclpy|rcl_interfaces|\w+_msgs|std_srvs|ament_index_python)\b')
    cores = sorted(SRC.glob('*/*/core/*.py'))
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
    adapter = SRC / 'cr_sim' / 'cr_sim' / 'ros_support' / 'rclpy_private.py'
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
LAYERS = ('cr_sim', 'cr_bridge', 'clis_modules', 'clis_learner', 'clis_app')
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
