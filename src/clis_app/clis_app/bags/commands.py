"""``clis record``, ``clis replay``, ``clis learn``, ``clis bag info``: runs as MCAP bags.

A bag is a rosbag2 folder (``NAME_0.mcap`` + ``metadata.yaml``) that ``ros2 bag info/play``,
Foxglove and PlotJuggler open (:mod:`clis_app.bags.mcap`). ``clis run --record bags/NAME``
records a run with the ``recorder`` node (:mod:`clis_app.bags.recorder_node`); ``clis record``
runs that node on its own. ``clis replay`` republishes a bag with its recorded timing and QoS
(:mod:`clis_app.bags.replay`). ``clis learn`` trains the modules from the episodes of bags
through the learner node's own path: the messages decoded by the same conversions, fed in
recorded order into the same :class:`~clis_learner.core.intake.EpisodeStream` (stream buffer,
episode memory, :class:`~clis_learner.core.learner.Learner`); the checkpoint it writes is what
``clis run --resume`` takes, and a bag of a ``clis run`` gives that run's parameters.

``clis`` draws its own ``ROS_DOMAIN_ID``: record or replay on a graph's domain with
``clis --domain-id N record ...`` (``clis run`` prints its domain).
"""

from __future__ import annotations

import argparse
from collections.abc import Iterable, Iterator
import os
from pathlib import Path
import sys
import time
from typing import Any

__all__ = ['register', 'learn_bags', 'feed_stream']

EXIT_OK, EXIT_DAMAGED, EXIT_USAGE = 0, 1, 2


def register(sub: argparse._SubParsersAction) -> None:
    from clis_learner.core.config import PRESET_NAMES
    fmt = argparse.RawDescriptionHelpFormatter
    p = sub.add_parser('record', help='record topics of the graph into a bag (MCAP)',
                       description=__doc__, formatter_class=fmt, epilog="""examples:
  clis --domain-id 7 record --out bags/mine             # every topic of the graph on domain 7
  clis --domain-id 7 record --topics /reward,/episode   # only these
""")
    p.add_argument('--out', type=Path, help='bag folder (default bags/record-DATE)')
    p.add_argument('--topics', default='', help='comma-separated topics (default: all of the '
                   'graph, and any other that appears)')
    p.add_argument('--compression', default='zstd', choices=('zstd', 'lz4', 'none'))
    p.set_defaults(func=_record)

    p = sub.add_parser('replay', help='republish a bag with its timing and QoS (and /clock)',
                       description=__doc__, formatter_class=fmt, epilog="""examples:
  clis --domain-id 7 replay bags/run              # at recorded speed, /clock from the bag
  clis replay bags/run --rate 10 --topics /odom,/markers --loop
""")
    p.add_argument('bag', type=Path)
    p.add_argument('--rate', type=float, default=1.0, help='speed factor (default 1)')
    p.add_argument('--topics', default='', help='comma-separated topics (default all)')
    p.add_argument('--loop', action='store_true', help='start again at the end')
    p.add_argument('--clock', type=float, default=20.0, metavar='HZ',
                   help='publish /clock at this rate from the bag time when the bag has no '
                        '/clock of its own (0 = never; default 20)')
    p.add_argument('--delay', type=float, default=1.0, metavar='S',
                   help='wait this long for subscribers to match before playing (default 1)')
    p.add_argument('--wait-for-subscribers', action='store_true',
                   help='also wait (up to 60 s) until every topic has a subscriber')
    p.add_argument('--quiet', action='store_true', help='no progress line')
    p.set_defaults(func=_replay)

    p = sub.add_parser('learn', help='learn offline from the episodes of bags; a checkpoint',
                       description=__doc__, formatter_class=fmt, epilog="""examples:
  clis learn bags/run --out results/offline/checkpoint.npz
  clis learn bags/a bags/b --resume results/run/X/checkpoint.npz --out ckpt.npz
  clis run --condition async --resume ckpt.npz      # continue live from it
""")
    p.add_argument('bags', type=Path, nargs='+', metavar='BAG')
    p.add_argument('--out', type=Path, default=Path('checkpoint.npz'),
                   help='checkpoint to write (default checkpoint.npz)')
    p.add_argument('--condition', help="the modules (default: the bag's, as recorded by "
                   'clis run, else those whose proposals it holds)')
    p.add_argument('--resume', type=Path, help='start from this checkpoint')
    p.add_argument('--preset', default=None, choices=PRESET_NAMES(),
                   help="parameter preset, as clis run --preset (default: the bag's run's, "
                        'found by the parameter hash the bag records, else improved)')
    p.add_argument('--params', type=Path, action='append', default=[], metavar='FILE',
                   help='ROS parameter file overriding config/clis.yaml (as given to clis run)')
    p.add_argument('--arena', default=None, help="arena file (default: the bag's, else "
                   'config/arena.yaml)')
    p.add_argument('--namespace', default='/', help='namespace of the graph in the bag')
    p.add_argument('--quiet', action='store_true', help='no line per episode')
    p.set_defaults(func=_learn)

    p = sub.add_parser('bag', help='inspect bags (clis bag info BAG)', description=__doc__,
                       formatter_class=fmt)
    bag_sub = p.add_subparsers(dest='bag_command', metavar='ACTION')
    bag_sub.required = True
    q = bag_sub.add_parser('info', help='topics, types, counts, duration (like ros2 bag info); '
                           'a damaged bag: what is wrong and how much is readable (exit 1)')
    q.add_argument('bag', type=Path)
    q.set_defaults(func=_info)


# ---------------------------------------------------------------------------- info / record

def _info(args: argparse.Namespace) -> int:
    from clis_app.bags.mcap import BagError, bag_info, format_info
    try:
        info = bag_info(args.bag)
    except (BagError, OSError) as exc:
        print(f'clis bag info: {exc}', file=sys.stderr)
        return EXIT_USAGE
    print(format_info(info))
    return EXIT_DAMAGED if info.damage else EXIT_OK


def _record(args: argparse.Namespace) -> int:
    from clis_app.bags import recorder_node
    out = args.out or Path('bags') / f'record-{time.strftime("%Y%m%d-%H%M%S")}'
    print(f'clis record: into {out}, ROS_DOMAIN_ID {os.environ.get("ROS_DOMAIN_ID")}; Ctrl-C '
          'finishes the bag', file=sys.stderr, flush=True)
    ros = ['recorder', '--ros-args', '-p', f'recorder.path:={out}',
           '-p', f'recorder.compression:={args.compression}', '-p', 'use_sim_time:=false']
    if args.topics:
        ros += ['-p', f'recorder.topics:={args.topics}']
    try:
        recorder_node.main(ros)
    except SystemExit as exc:
        return int(exc.code or 0)
    return EXIT_OK


def _replay(args: argparse.Namespace) -> int:
    from clis_app.bags.replay import replay
    return replay(args)


# ---------------------------------------------------------------------------- learn

def feed_stream(stream: Any, messages: Iterable[Any], namespace: str = '/') -> Iterator[Any]:
    """Feed a bag's messages (:class:`~clis_app.bags.mcap.BagMessage`, recorded order) to an
    :class:`~clis_learner.core.intake.EpisodeStream` through the learner node's routing
    (:mod:`clis_learner.intake_topics`); yield each closed episode
    (:class:`~clis_learner.core.intake.Closed`). An episode that ended is closed at the next
    start or at the end of the messages (all its records are in by then)."""
    from clis_learner.intake_topics import EPISODE, feed_episode, feed_record, record_topics
    from rclpy.serialization import deserialize_message

    routes = {topic: (kind, msg_type)
              for kind, topic, msg_type in record_topics(stream.names, namespace)}
    ns = '/' + namespace.strip('/') + '/' if namespace.strip('/') else '/'
    episode = ns + EPISODE[0]
    for m in messages:
        if m.topic in routes:
            kind, msg_type = routes[m.topic]
            try:
                feed_record(stream, kind, deserialize_message(m.data, msg_type))
            except (ValueError, KeyError):
                pass                                    # the live node ignores it too
        elif m.topic == episode:
            ev = feed_episode(stream, deserialize_message(m.data, EPISODE[1]))
            if ev.closed is not None:
                yield ev.closed
    if stream.closing is not None:
        yield stream.close()


def _condition_of(bag: Any, names: set[str]) -> str | None:
    cond = bag.custom_data.get('condition')
    if cond:
        return cond
    from clis_modules.core.plugin import solo_condition
    found = {t.rsplit('/', 2)[-2] for t in names if t.endswith('/proposal')}
    if len(found) == 1:                          # one module: on its own period
        return solo_condition(found.pop())
    return None


def learn_bags(bags: list[Path], out: Path, condition: str | None = None,
               resume: Path | None = None, params_files: list[Path] | None = None,
               arena: str | None = None, namespace: str = '/', say=print,
               preset: str | None = None) -> dict[str, Any]:
    """Learn from the episodes of ``bags`` in order; write the checkpoint ``out``.

    The parameters are config/clis.yaml with ``preset``'s file and ``params_files``, as ``clis
    run`` gives them; ``preset`` None: the preset whose parameters have the hash the first bag
    records (what its run used), else the default preset.

    Returns a summary: ``{'episodes': learned, 'skipped': not learned, 'version': ...,
    'condition': ..., 'damaged': [messages]}``. Raises ValueError (bad input) or
    :class:`~clis_app.bags.mcap.BagError` (a bag that cannot be opened).
    """
    from clis_base.params import config_dir, ros_parameters
    from clis_learner.core.checkpoint import load_checkpoint, save_checkpoint
    from clis_learner.core.config import (
        DEFAULT_PRESET,
        PRESET_NAMES,
        ClisParams,
        load_clis_params,
        params_hash,
        preset_overrides,
    )
    from clis_learner.core.intake import EpisodeStream
    from clis_modules.core.modules import arena_map, make_modules
    from clis_modules.core.plugin import parse_condition
    from cr_sim.core.arena import load_arena

    from clis_app.bags.mcap import BagError, BagReader, bag_info

    readers = [BagReader(b) for b in bags]
    first = readers[0]
    topics = set(bag_info(bags[0]).topics)
    condition = condition or _condition_of(first, topics)
    if condition is None:
        raise ValueError(f'give --condition (TIMING:MODULE+... or innate, view, place, sync, '
                         f'async): {bags[0]} does not say')
    parse_condition(condition)                   # raises naming the form
    given: dict[str, Any] = {}
    # the sections of the CLIS parameters (the fixed ones and the module instances)
    sections = set(ClisParams.__dataclass_fields__) | set(
        ros_parameters(config_dir() / 'clis.yaml', '/**'))
    for f in params_files or []:
        values = ros_parameters(f, '/**')
        given.update({k: v for k, v in values.items() if k in sections})
    recorded = first.custom_data.get('params_hash')

    def with_preset(name: str) -> ClisParams:
        return load_clis_params(overrides={**preset_overrides(name), **given} or None)
    if preset is None:                        # the bag's run's, else the default
        preset = next((n for n in PRESET_NAMES() if recorded
                       and params_hash(with_preset(n)) == recorded), DEFAULT_PRESET)
    clis = with_preset(preset)
    arena = arena if arena is not None else first.custom_data.get('arena_file', '')
    modules = make_modules(clis, condition, *arena_map(load_arena(arena or None)))
    hash_ = params_hash(clis)
    if recorded and recorded != hash_:
        say(f'clis learn: warning: {bags[0]} was recorded with CLIS parameters {recorded}, '
            f"these are {hash_} (give the run's --preset and --params files): the parameters "
            "will differ from the run's")
    version = 0
    if resume is not None:
        version = int(load_checkpoint(resume, modules, hash_)['extra'].get('version', 0))
    summary: dict[str, Any] = {'episodes': 0, 'skipped': 0, 'condition': condition,
                               'preset': preset, 'damaged': []}
    seed = int(first.custom_data.get('seed', 0) or 0)
    last_episode = -1
    for bag, reader in zip(bags, readers):
        stream = EpisodeStream(modules, clis, condition, seed, version)   # new clock per run
        try:
            for closed in feed_stream(stream, reader.messages_by_time(), namespace):
                if closed.learned:
                    summary['episodes'] += 1
                    last_episode = closed.episode
                else:
                    summary['skipped'] += 1
                say(f'{bag.name}: episode {closed.episode}: '
                    f'{"learned" if closed.learned else "not learned (start not recorded)"}, '
                    f'{closed.row["event"]} after {closed.row["duration"]:.2f} s, acted '
                    f'{closed.row["behaviour"]}'
                    + ('' if closed.row['complete'] else
                       " (WARNING: its rewards do not sum to the simulator's return)"))
        except BagError as exc:
            summary['damaged'].append(str(exc))
            say(f'clis learn: {exc}; learned from the episodes before the damage')
            if stream.closing is not None:
                closed = stream.close()
                summary['episodes' if closed.learned else 'skipped'] += 1
        version = stream.version
    summary['version'] = version
    out.parent.mkdir(parents=True, exist_ok=True)
    save_checkpoint(out, modules, hash_, {'version': version, 'episode': last_episode,
                                          'condition': condition, 'seed': seed,
                                          'bags': [str(b) for b in bags]})
    return summary


def _learn(args: argparse.Namespace) -> int:
    from clis_base.params import ConfigError
    from clis_learner.core.checkpoint import CheckpointError

    from clis_app.bags.mcap import BagError
    for b in args.bags:
        if not b.exists():
            print(f'clis learn: {b}: no such bag', file=sys.stderr)
            return EXIT_USAGE
    for f in args.params:
        if not f.is_file():
            print(f'clis learn: --params {f}: no such file', file=sys.stderr)
            return EXIT_USAGE
    say = (lambda *_: None) if args.quiet else (lambda s: print(s, file=sys.stderr,
                                                                 flush=True))
    t0 = time.monotonic()
    try:
        s = learn_bags(args.bags, args.out, args.condition, args.resume, args.params,
                       args.arena, args.namespace, say, args.preset)
    except (BagError, CheckpointError, ConfigError, ValueError) as exc:
        print(f'clis learn: {exc}', file=sys.stderr)
        return EXIT_USAGE
    print(f'clis learn: {s["episodes"]} episodes learned ({s["condition"]}, '
          f'{s["preset"]} preset; '
          f'{s["skipped"]} not learned), version {s["version"]}, in '
          f'{time.monotonic() - t0:.1f} s: {args.out}', file=sys.stderr)
    return EXIT_DAMAGED if s['damaged'] else EXIT_OK
