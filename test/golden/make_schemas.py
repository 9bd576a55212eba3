"""Write the golden ``ros2msg`` schema texts of test/golden/ros2msg/ (test_bag_readers.py).

Each golden text is what rosbag2 (Jazzy) records as the MCAP schema of a message type: its
``LocalMessageDefinitionSource::get_full_text`` over the ``.msg`` files of the venv's
``share/`` folder, followed step by step here, independently of the project's writer
(clis_learner.core.bag, which the test compares with these files):

* the root's ``.msg`` file, bytes as installed (comments and blank lines kept);
* its dependencies: every match of ``(?:^|\\n)\\s*([a-zA-Z0-9_/]+)(?:\\[[^\\]]*\\])?\\s+`` in
  that raw text that is not one of rosbag2's 14 primitive names; a name without ``/`` gets
  the package of the file in front (``Vector3`` in geometry_msgs is ``geometry_msgs/Vector3``),
  a name with ``/`` is kept as written (``std_msgs/Header``); a ``std::set``, so byte order;
* for each dependency not seen before in this text (the root is not counted as seen): ``\\n``,
  80 ``=``, ``\\n``, ``MSG: `` + the name, ``\\n``, then its own full text (depth first);
* a name ``pkg/Type`` or ``pkg/msg/Type`` is looked up as ``share/pkg/msg/Type.msg``.

Run from the repository root, after a change of the ROS 2 interface packages (or of the types
the project records, :data:`TYPES`)::

    .venv/bin/python test/golden/make_schemas.py
"""

from __future__ import annotations

import argparse
from pathlib import Path
import re

HERE = Path(__file__).resolve().parent
REPO = HERE.parent.parent
#: Every message type the project records in its bags (``clis run --record``) or serves
#: with the same schemas (the live Foxglove view's robot path).
TYPES = (
    'diagnostic_msgs/msg/DiagnosticArray',
    'geometry_msgs/msg/TwistStamped',
    'geometry_msgs/msg/Vector3Stamped',
    'nav_msgs/msg/OccupancyGrid',
    'nav_msgs/msg/Odometry',
    'nav_msgs/msg/Path',
    'rosgraph_msgs/msg/Clock',
    'sensor_msgs/msg/JointState',
    'sensor_msgs/msg/LaserScan',
    'visualization_msgs/msg/MarkerArray',
)
ROSBAG2_PRIMITIVE_TYPES = ('bool', 'byte', 'char', 'float32', 'float64', 'int8', 'uint8',
                           'int16', 'uint16', 'int32', 'uint32', 'int64', 'uint64', 'string')
FIELD_TYPE = re.compile(rb'(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:\[[^\]]*\])?\s+')
TYPE_NAME = re.compile(r'([a-zA-Z0-9_]+)/(?:msg/|srv/)?([a-zA-Z0-9_]+)')


def msg_file(share: Path, name: str) -> Path:
    match = TYPE_NAME.fullmatch(name)
    if match is None:
        raise SystemExit(f'{name}: not a pkg/Type name')
    return share / match.group(1) / 'msg' / f'{match.group(2)}.msg'


def get_full_text(share: Path, root: str) -> bytes:
    """rosbag2's ``get_full_text`` of ``root`` (a ``.msg`` type) over ``share``."""
    seen_deps: set[str] = set()

    def append_recursive(name: str, depth: int) -> bytes:
        assert depth > 0, f'{root}: recursion'
        text = msg_file(share, name).read_bytes()
        package = TYPE_NAME.fullmatch(name).group(1)
        dependencies = set()
        for found in FIELD_TYPE.finditer(text):
            field_type = found.group(1).decode('ascii')
            if field_type in ROSBAG2_PRIMITIVE_TYPES:
                continue
            dependencies.add(field_type if '/' in field_type else package + '/' + field_type)
        result = text
        for dep in sorted(dependencies, key=lambda d: d.encode()):
            if dep not in seen_deps:
                seen_deps.add(dep)
                result += b'\n' + b'=' * 80 + b'\n' + b'MSG: ' + dep.encode() + b'\n'
                result += append_recursive(dep, depth - 1)
        return result

    return append_recursive(root, 50)


def golden_path(msg_type: str) -> Path:
    """Where the golden text of ``msg_type`` (``pkg/msg/Type``) is kept."""
    return HERE / 'ros2msg' / f'{msg_type}.txt'


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    share = REPO / '.venv' / 'share'
    if not (share / 'std_msgs').is_dir():               # a venv on a system ROS 2 (make setup)
        share = Path('/opt/ros/jazzy/share')
    parser.add_argument('--share', type=Path, default=share,
                        help='the share/ folder of the ROS 2 interface packages (default: the '
                             "venv's, else /opt/ros/jazzy/share)")
    parser.add_argument('--check', action='store_true',
                        help='write nothing; exit 1 if a golden file differs')
    args = parser.parse_args()
    stale = []
    for msg_type in TYPES:
        text = get_full_text(args.share, msg_type)
        path = golden_path(msg_type)
        if args.check:
            if not path.is_file() or path.read_bytes() != text:
                stale.append(str(path))
            continue
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(text)
        print(f'{path.relative_to(REPO)}: {len(text)} bytes')
    if stale:
        raise SystemExit('stale golden files: ' + ', '.join(stale))


if __name__ == '__main__':
    main()
