"""rosbag2-compatible MCAP bags: writer, damage-reporting reader, ``info`` (no ROS imports).

A *bag* is a folder ``NAME/`` with ``NAME_0.mcap`` and ``metadata.yaml`` (rosbag2 version 9,
what ``ros2 bag play`` needs of a folder); a lone ``.mcap`` file is a bag too (rosbag2 plays it
without metadata). The MCAP file is what rosbag2's (Jazzy) MCAP storage plugin writes:

* header profile ``ros2``; message encoding ``cdr`` (the serialized bytes as they came off the
  wire, never decoded);
* one schema per type, named ``pkg/msg/Type``, encoding ``ros2msg``, byte for byte what
  rosbag2_cpp's ``LocalMessageDefinitionSource`` writes: the type's ``.msg`` text followed by
  every dependency, each after a line of 80 ``=`` and ``MSG: pkg/Type`` spelled as the
  ``.msg`` file references it (:func:`message_definition`, from the ``share/<pkg>/msg/``
  folders of the ament prefixes; :func:`definition` for the ``.idl`` fallback);
* channel metadata ``offered_qos_profiles`` (a YAML list of QoS maps, :func:`qos_yaml`) and
  ``topic_type_hash`` (``RIHS01_...``);
* chunks (zstd), message indexes, statistics and the summary (the ``mcap`` writer's
  defaults), and a ``rosbag2`` metadata record holding the serialized ``metadata.yaml``.

Crash safety: :meth:`BagWriter.flush` closes the open chunk and hands it to the OS; the
recorder calls it every ``flush_interval`` s and ``metadata.yaml`` is rewritten atomically
each time, so a killed recorder leaves a file readable up to its last flushed chunk.

:class:`BagReader` streams the records in file order, validating CRCs. A truncated or corrupt
file raises :class:`BagError` naming the file and what is wrong *after* every message before
the damage was yielded; :func:`bag_info` reports how much was readable.

One piece, the format: the writer, the reader that reports damage and ``metadata.yaml`` agree
on one layout (schema text, channel metadata, chunking, the metadata record) that rosbag2 and
Foxglove read, and the reader's damage report depends on how the writer lays out and flushes
chunks; apart, a change to one side would not be seen by the other.
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
import heapq
import json
import os
from pathlib import Path
import re
import time
from typing import Any

import yaml

from clis_app import files

__all__ = ['BagError', 'BagWriter', 'BagReader', 'BagMessage', 'TopicInfo', 'BagInfo',
           'METADATA_VERSION', 'bag_topics', 'definition', 'message_definition', 'type_hash',
           'qos_yaml', 'parse_qos_yaml', 'bag_info', 'format_info', 'mcap_path']

#: ``rosbag2_bagfile_information.version`` written (rosbag2 in Jazzy).
METADATA_VERSION = 9
SEPARATOR = '=' * 80
#: The field types rosbag2 (Jazzy) does not look up as definitions (``wstring`` is not one).
ROSBAG2_PRIMITIVES = frozenset({'bool', 'byte', 'char', 'float32', 'float64', 'int8', 'uint8',
                                'int16', 'uint16', 'int32', 'uint32', 'int64', 'uint64',
                                'string'})
#: rosbag2_cpp's ``ROSBAG2_CPP_LOCAL_MESSAGE_DEFINITION_SOURCE_MAX_RECURSION_DEPTH``.
MAX_RECURSION_DEPTH = 50
# rosbag2_cpp's regexes (local_message_definition_source.cpp, Jazzy), on the raw bytes:
# a type name "foo_msgs/Bar" or "foo_msgs/msg/Bar"
_PACKAGE_TYPENAME = re.compile(r'([a-zA-Z0-9_]+)/(?:msg/|srv/)?([a-zA-Z0-9_]+)', re.ASCII)
# a .msg field's type at the start of a line ("foo_msgs/Bar" in "foo_msgs/Bar[] bar")
_MSG_FIELD_TYPE = re.compile(rb'(?:^|\n)\s*([a-zA-Z0-9_/]+)(?:\[[^\]]*\])?\s+')
# an .idl dependency ("foo_msgs/msg/Bar" in #include <foo_msgs/msg/Bar.idl>)
_IDL_FIELD_TYPE = re.compile(rb'(?:^|\n)#include\s+(?:"|<)([a-zA-Z0-9_/]+)\.idl(?:"|>)')
#: rmw's "infinite" duration, as rosbag2 writes it (sec, nsec).
INFINITE = (9223372036, 854775807)


class _Dumper(yaml.SafeDumper):
    """Plain YAML: no anchors/aliases for repeated maps (rosbag2's parser has none)."""

    def ignore_aliases(self, data: Any) -> bool:
        return True


def _dump(data: Any) -> str:
    return yaml.dump(data, Dumper=_Dumper, default_flow_style=False, sort_keys=False)


class BagError(ValueError):
    """A bag that cannot be (fully) read or written; the message names the file."""


# ---------------------------------------------------------------------------- definitions

def _share_dirs(prefixes: Sequence[str | os.PathLike] | None) -> list[Path]:
    if prefixes is None:
        prefixes = [p for p in os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) if p]
    return [Path(p) / 'share' for p in prefixes]


def _split_type(msg_type: str) -> tuple[str, str, str]:
    parts = msg_type.split('/')
    if len(parts) == 2:
        return parts[0], 'msg', parts[1]
    if len(parts) == 3:
        return parts[0], parts[1], parts[2]
    raise BagError(f'type {msg_type!r}: expected pkg/msg/Type')


def _find_interface(msg_type: str, ext: str, shares: list[Path]) -> Path:
    pkg, ns, name = _split_type(msg_type)
    for share in shares:
        path = share / pkg / ns / f'{name}{ext}'
        if path.is_file():
            return path
    raise BagError(f'type {msg_type}: no {ns}/{name}{ext} in the share/{pkg} folder of any '
                   f'prefix of AMENT_PREFIX_PATH ({", ".join(map(str, shares)) or "empty"}): '
                   'source env.sh')


class _DefinitionNotFoundError(BagError):
    """rosbag2's ``DefinitionNotFoundError``: no such package or definition file."""


class _TypenameNotUnderstoodError(BagError):
    """rosbag2's ``TypenameNotUnderstoodError``: a name that is not ``pkg/[msg/]Type``."""


def _package_share(pkg: str, shares: list[Path]) -> Path:
    """``ament_index_cpp::get_package_share_directory``: the first prefix whose ament index
    lists ``pkg`` (else, for a prefix without an index, the first with ``share/pkg``)."""
    for share in shares:
        if (share / 'ament_index' / 'resource_index' / 'packages' / pkg).is_file():
            return share / pkg
    for share in shares:
        if (share / pkg).is_dir():
            return share / pkg
    raise _DefinitionNotFoundError(f'package {pkg}: not in the ament index of any prefix of '
                    f'AMENT_PREFIX_PATH ({", ".join(map(str, shares)) or "empty"}): '
                    'source env.sh')


def _delimiter(name: str, fmt: str) -> bytes:
    return f'{SEPARATOR}\n{fmt.upper()}: {name}\n'.encode()


class _DefinitionSource:
    """rosbag2_cpp's ``LocalMessageDefinitionSource`` (Jazzy), for message types.

    A definition is found by its name as written (``pkg/Type`` or ``pkg/msg/Type``) in
    ``share/pkg/msg/Type.msg`` (or ``.idl``); its text is kept as bytes, untouched. Its
    dependencies are the field types that rosbag2's regex matches in that raw text (comments
    included): a type without a package takes the package of the file (``Vector3`` in a
    geometry_msgs file is ``geometry_msgs/Vector3``), ``pkg/Type`` is kept as written; they
    are visited in byte order.
    """

    def __init__(self, shares: list[Path]) -> None:
        self.shares = shares
        self.specs: dict[tuple[str, str], tuple[bytes, list[str]]] = {}

    def load(self, name: str, fmt: str) -> tuple[bytes, list[str]]:
        """``load_message_spec``: the text and the sorted dependencies of ``name``."""
        key = (name, fmt)
        if key not in self.specs:
            match = _PACKAGE_TYPENAME.fullmatch(name)
            if match is None:
                raise _TypenameNotUnderstoodError(f'type {name!r}: not understood (pkg/msg/Type)')
            pkg, short = match.group(1), match.group(2)
            path = _package_share(pkg, self.shares) / 'msg' / f'{short}.{fmt}'
            if not path.is_file():
                raise _DefinitionNotFoundError(f'type {name}: no msg/{short}.{fmt} in '
                                               f'{path.parent.parent}')
            text = path.read_bytes()
            if fmt == 'msg':
                deps = set()
                for found in _MSG_FIELD_TYPE.findall(text):
                    dep = found.decode()
                    if dep not in ROSBAG2_PRIMITIVES:
                        deps.add(dep if '/' in dep else f'{pkg}/{dep}')
            else:
                deps = {found.decode() for found in _IDL_FIELD_TYPE.findall(text)}
            self.specs[key] = (text, sorted(deps, key=str.encode))
        return self.specs[key]

    def full_text(self, root: str, fmt: str, seen: set[tuple[str, str]]) -> bytes:
        """``append_recursive``: the text, then each dependency not seen yet, depth first."""
        def append(name: str, depth: int) -> bytes:
            if depth <= 0:
                raise BagError(f'type {root}: reached max recursion depth resolving its '
                               'definition')
            text, deps = self.load(name, fmt)
            out = [text]
            for dep in deps:
                if (dep, fmt) not in seen:
                    seen.add((dep, fmt))
                    out += [b'\n', _delimiter(dep, fmt), append(dep, depth - 1)]
            return b''.join(out)
        return append(root, MAX_RECURSION_DEPTH)


def definition(msg_type: str, prefixes: Sequence[str | os.PathLike] | None = None
               ) -> tuple[str, bytes]:
    """``(encoding, schema data)`` of ``msg_type`` exactly as rosbag2 (Jazzy) records it.

    rosbag2_cpp's ``LocalMessageDefinitionSource::get_full_text``: the ``.msg`` definition
    with its dependencies (``ros2msg``, :func:`message_definition`); when a ``.msg`` file is
    missing, the ``.idl`` ones (``ros2idl``: ``IDL: pkg/msg/Type`` first, then each
    ``#include``d dependency after a line of 80 ``=`` and ``IDL: pkg/msg/Dep``); a name it
    does not understand, or no definition at all, gives ``('unknown', b'')``, as rosbag2's
    writer records it (``empty_message_definition_for``).

    Parameters
    ----------
    msg_type : str
        ``pkg/msg/Type`` (or ``pkg/Type``).
    prefixes : sequence of path, optional
        Install prefixes (default ``$AMENT_PREFIX_PATH``).
    """
    if '/srv/' in msg_type:             # a service event topic: rosbag2 finds no .srv of it
        return 'unknown', b''
    source = _DefinitionSource(_share_dirs(prefixes))
    seen: set[tuple[str, str]] = set()
    try:
        return 'ros2msg', source.full_text(msg_type, 'msg', seen)
    except _TypenameNotUnderstoodError:
        return 'unknown', b''
    except _DefinitionNotFoundError:
        pass
    try:
        return 'ros2idl', _delimiter(msg_type, 'idl') + source.full_text(msg_type, 'idl', seen)
    except (_TypenameNotUnderstoodError, _DefinitionNotFoundError):
        return 'unknown', b''


def message_definition(msg_type: str,
                       prefixes: Sequence[str | os.PathLike] | None = None) -> str:
    """The ``ros2msg`` schema text of ``msg_type`` with its dependencies, as rosbag2 writes it.

    The type's ``.msg`` text as installed, then every type it uses (depth first, each once,
    in byte order at each level), each after a line of 80 ``=`` and ``MSG: `` with the name
    as the ``.msg`` file spells it: ``std_msgs/Header`` for a field ``std_msgs/Header header``,
    ``geometry_msgs/Vector3`` for a field ``Vector3 linear`` of a geometry_msgs type
    (rosbag2_cpp's ``LocalMessageDefinitionSource::get_full_text``, Jazzy). Foxglove finds a
    dependency only under that spelling (docs/bags.md).

    Parameters
    ----------
    msg_type : str
        ``pkg/msg/Type`` (or ``pkg/Type``).
    prefixes : sequence of path, optional
        Install prefixes whose ``share/<pkg>/msg/`` hold the ``.msg`` files (default
        ``$AMENT_PREFIX_PATH``).

    Raises
    ------
    BagError
        A ``.msg`` file (of the type or of a dependency) is not installed, or the name is not
        ``pkg/msg/Type``.
    """
    source = _DefinitionSource(_share_dirs(prefixes))
    return source.full_text(msg_type, 'msg', set()).decode()


def type_hash(msg_type: str, prefixes: Sequence[str | os.PathLike] | None = None) -> str:
    """``RIHS01_...`` of ``msg_type`` from its ``.json`` type description (what rosidl
    generated next to the ``.msg``); the recorder prefers the publisher's."""
    path = _find_interface(msg_type, '.json', _share_dirs(prefixes))
    name = '/'.join(_split_type(msg_type))
    for entry in json.loads(path.read_text()).get('type_hashes', []):
        if entry.get('type_name') == name:
            return str(entry['hash_string'])
    raise BagError(f'type {msg_type}: {path} holds no hash of it')


# ---------------------------------------------------------------------------- QoS

def _duration(ns: int | None) -> dict[str, int]:
    if ns is None or ns <= 0 or ns >= 2**63 - 1:        # unset/infinite: rmw's infinite
        sec, nsec = (0, 0) if ns == 0 or ns is None else INFINITE
    else:
        sec, nsec = divmod(int(ns), 1_000_000_000)
    return {'sec': int(sec), 'nsec': int(nsec)}


def qos_dict(history: str, depth: int, reliability: str, durability: str,
             deadline_ns: int | None = 0, lifespan_ns: int | None = 0,
             liveliness: str = 'automatic', lease_ns: int | None = 0,
             avoid_ros_namespace_conventions: bool = False) -> dict[str, Any]:
    """One QoS map of ``offered_qos_profiles`` (rosbag2's v9 keys and value names:
    ``keep_last``/``keep_all``, ``reliable``/``best_effort``, ``volatile``/``transient_local``,
    ``automatic``/``manual_by_topic``; durations ``{sec, nsec}``)."""
    return {'history': history, 'depth': int(depth), 'reliability': reliability,
            'durability': durability, 'deadline': _duration(deadline_ns),
            'lifespan': _duration(lifespan_ns), 'liveliness': liveliness,
            'liveliness_lease_duration': _duration(lease_ns),
            'avoid_ros_namespace_conventions': bool(avoid_ros_namespace_conventions)}


def qos_yaml(profiles: Sequence[Mapping[str, Any]]) -> str:
    """The ``offered_qos_profiles`` text of a channel: a YAML list of QoS maps."""
    return _dump([dict(p) for p in profiles]).strip() if profiles else '[]'


def parse_qos_yaml(text: str) -> list[dict[str, Any]]:
    """Inverse of :func:`qos_yaml`; ``[]`` for an empty text."""
    if not text.strip():
        return []
    out = yaml.safe_load(text)
    if not isinstance(out, list) or not all(isinstance(p, dict) for p in out):
        raise BagError(f'offered_qos_profiles is not a list of maps: {text[:80]!r}')
    return out


# ---------------------------------------------------------------------------- writer

@dataclass
class TopicInfo:
    """One topic of a bag: type, QoS, hash, message count and time span (ns)."""

    name: str
    type: str
    qos_profiles: list[dict[str, Any]] = field(default_factory=list)
    type_hash: str = ''
    count: int = 0
    first_ns: int | None = None
    last_ns: int | None = None

    def seen(self, log_ns: int) -> None:
        self.count += 1
        self.first_ns = log_ns if self.first_ns is None else min(self.first_ns, log_ns)
        self.last_ns = log_ns if self.last_ns is None else max(self.last_ns, log_ns)


def mcap_path(bag: str | os.PathLike) -> Path:
    """The ``.mcap`` file of a bag folder (the one named in ``metadata.yaml``, else the only
    one) or the file itself."""
    bag = Path(bag)
    if bag.is_file():
        return bag
    if not bag.is_dir():
        raise BagError(f'{bag}: no such bag (a folder with metadata.yaml or an .mcap file)')
    meta = bag / 'metadata.yaml'
    if meta.is_file():
        try:
            info = yaml.safe_load(meta.read_text())['rosbag2_bagfile_information']
            names = info.get('relative_file_paths') or []
        except (yaml.YAMLError, KeyError, TypeError) as exc:
            raise BagError(f'{meta}: not a rosbag2 metadata file ({exc})') from None
        if names and (bag / names[0]).is_file():
            return bag / names[0]
    files = sorted(bag.glob('*.mcap'))
    if len(files) != 1:
        raise BagError(f'{bag}: expected one .mcap file, found {len(files)}')
    return files[0]


class BagWriter:
    """Writes one bag folder ``path/`` (``path/NAME_0.mcap`` + ``path/metadata.yaml``).

    Parameters
    ----------
    path : path-like
        The bag folder; it must not hold a bag already.
    chunk_size : int
        Uncompressed bytes per chunk (rosbag2's default is 768 KiB).
    compression : str
        ``'zstd'``, ``'lz4'`` or ``'none'`` (per chunk).
    prefixes : sequence of path, optional
        Where the ``.msg`` definitions are (default ``$AMENT_PREFIX_PATH``).
    custom_data : Mapping[str, str], optional
        ``custom_data`` of ``metadata.yaml`` (e.g. the run's condition and seed).
    """

    def __init__(self, path: str | os.PathLike, chunk_size: int = 768 * 1024,
                 compression: str = 'zstd', prefixes: Sequence[str] | None = None,
                 custom_data: Mapping[str, str] | None = None) -> None:
        from mcap.writer import CompressionType, Writer
        self.path = Path(path)
        if (self.path / 'metadata.yaml').exists() or any(self.path.glob('*.mcap')):
            raise BagError(f'{self.path}: holds a bag already: choose another name')
        self.path.mkdir(parents=True, exist_ok=True)
        self.file = self.path / f'{self.path.name}_0.mcap'
        kinds = {'zstd': CompressionType.ZSTD, 'lz4': CompressionType.LZ4,
                 'none': CompressionType.NONE}
        if compression not in kinds:
            raise BagError(f'compression {compression!r}: one of {sorted(kinds)}')
        self.compression = compression
        self.prefixes = prefixes
        self.custom_data = {str(k): str(v) for k, v in (custom_data or {}).items()}
        self._fh = open(self.file, 'wb')
        self._writer = Writer(self._fh, chunk_size=chunk_size, compression=kinds[compression])
        self._writer.start(profile='ros2', library='clis_app')
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self.topics: dict[str, TopicInfo] = {}
        self.closed = False
        self.write_metadata()

    def add_topic(self, topic: str, msg_type: str,
                  qos_profiles: Sequence[Mapping[str, Any]] = (), hash_: str = '') -> None:
        """Register ``topic`` (once) with its type, offered QoS and type hash (default: from
        the type's description). The schema is :func:`definition`'s: a type whose ``.msg``
        is not installed is recorded with its ``.idl`` definitions, or with an empty schema of
        encoding ``unknown``, as rosbag2 does."""
        if topic in self._channels:
            return
        msg_type = '/'.join(_split_type(msg_type))
        if msg_type not in self._schemas:
            try:
                encoding, data = definition(msg_type, self.prefixes)
            except (BagError, OSError):          # as rosbag2: recorded, definition unknown
                encoding, data = 'unknown', b''
            self._schemas[msg_type] = self._writer.register_schema(msg_type, encoding, data)
        if not hash_:
            try:
                hash_ = type_hash(msg_type, self.prefixes)
            except (BagError, OSError, ValueError):
                hash_ = ''
        profiles = [dict(p) for p in qos_profiles]
        self._channels[topic] = self._writer.register_channel(
            topic, 'cdr', self._schemas[msg_type],
            {'offered_qos_profiles': qos_yaml(profiles), 'topic_type_hash': hash_})
        self.topics[topic] = TopicInfo(topic, msg_type, profiles, hash_)

    def write(self, topic: str, data: bytes, log_ns: int, publish_ns: int | None = None,
              sequence: int = 0) -> None:
        """One serialized (CDR) message of ``topic``, received at ``log_ns`` [ns since the
        epoch], published at ``publish_ns`` (default ``log_ns``)."""
        channel = self._channels.get(topic)
        if channel is None:
            raise BagError(f'{self.file}: topic {topic} was not added')
        self._writer.add_message(channel, int(log_ns), bytes(data),
                                 int(log_ns if publish_ns is None else publish_ns),
                                 sequence & 0xFFFFFFFF)
        self.topics[topic].seen(int(log_ns))

    def flush(self) -> None:
        """Close the open chunk, hand everything to the OS and rewrite ``metadata.yaml``:
        a crash after this leaves every message so far readable."""
        self._writer.flush()
        self._fh.flush()
        self.write_metadata()

    @property
    def message_count(self) -> int:
        return sum(t.count for t in self.topics.values())

    def metadata(self) -> dict[str, Any]:
        """``metadata.yaml`` (rosbag2 version 9) of what was written so far."""
        return metadata_dict(self.topics, self.file.name, self.compression,
                             self.custom_data)

    def write_metadata(self) -> None:
        files.write_text(self.path / 'metadata.yaml', _dump(self.metadata()), fsync=True)

    def close(self) -> None:
        """Finish the file (summary, indexes, footer) and write the final ``metadata.yaml``."""
        if self.closed:
            return
        self.closed = True
        text = _dump(self.metadata())
        self._writer.add_metadata('rosbag2', {'serialized_metadata': text})
        self._writer.finish()
        self._fh.flush()
        os.fsync(self._fh.fileno())
        self._fh.close()
        self.write_metadata()

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def metadata_dict(topics: Mapping[str, TopicInfo], file_name: str, compression: str = '',
                  custom_data: Mapping[str, str] | None = None) -> dict[str, Any]:
    """The ``rosbag2_bagfile_information`` of one-file bag with ``topics``."""
    firsts = [t.first_ns for t in topics.values() if t.first_ns is not None]
    lasts = [t.last_ns for t in topics.values() if t.last_ns is not None]
    start = min(firsts) if firsts else 0
    duration = (max(lasts) - start) if lasts else 0
    count = sum(t.count for t in topics.values())
    del compression                        # chunk compression is MCAP's, not rosbag2's
    return {'rosbag2_bagfile_information': {
        'version': METADATA_VERSION,
        'storage_identifier': 'mcap',
        'duration': {'nanoseconds': int(duration)},
        'starting_time': {'nanoseconds_since_epoch': int(start)},
        'message_count': int(count),
        'topics_with_message_count': [
            {'topic_metadata': {'name': t.name, 'type': t.type, 'serialization_format': 'cdr',
                                'offered_qos_profiles': t.qos_profiles,
                                'type_description_hash': t.type_hash},
             'message_count': int(t.count)} for t in topics.values()],
        'compression_format': '',
        'compression_mode': '',
        'relative_file_paths': [file_name],
        'files': [{'path': file_name,
                   'starting_time': {'nanoseconds_since_epoch': int(start)},
                   'duration': {'nanoseconds': int(duration)},
                   'message_count': int(count)}],
        'custom_data': dict(custom_data or {}),
        'ros_distro': 'jazzy',
    }}




# ---------------------------------------------------------------------------- reader

@dataclass(frozen=True)
class BagMessage:
    """One message of a bag: topic, type, the serialized CDR bytes, receive and publish time
    [ns since the epoch]."""

    topic: str
    type: str
    data: bytes
    log_ns: int
    publish_ns: int
    sequence: int = 0


class BagReader:
    """Streams every message of a bag folder or ``.mcap`` file, in file order.

    CRCs are checked. Damage (a truncated file, a corrupt record, a bad CRC) raises
    :class:`BagError` naming the file, the byte offset and what is wrong, once every message
    before it has been yielded; :attr:`damage` keeps the message.
    """

    def __init__(self, bag: str | os.PathLike) -> None:
        self.file = mcap_path(bag)
        self.topics: dict[str, TopicInfo] = {}
        self.custom_data: dict[str, str] = {}
        self.damage: str | None = None
        self.complete = False        # the footer was reached
        meta = self.file.parent / 'metadata.yaml'
        if meta.is_file() and Path(bag).is_dir():
            try:
                info = yaml.safe_load(meta.read_text())['rosbag2_bagfile_information']
                self.custom_data = dict(info.get('custom_data') or {})
            except (yaml.YAMLError, KeyError, TypeError):
                pass

    def messages(self, topics: Iterable[str] | None = None) -> Iterator[BagMessage]:
        """The messages (of ``topics`` only, if given), as stored."""
        from mcap.records import Channel, Footer, Header, Message, Metadata, Schema
        from mcap.stream_reader import StreamReader
        wanted = None if topics is None else set(topics)
        schemas: dict[int, str] = {}
        channels: dict[int, tuple[str, str]] = {}
        size = self.file.stat().st_size
        with open(self.file, 'rb') as fh:
            reader = StreamReader(fh, validate_crcs=True)
            records = reader.records
            last_ok = 0
            while True:
                try:
                    rec = next(records)
                except StopIteration:
                    break
                except Exception as exc:                    # noqa: BLE001 any decode failure
                    self.damage = self._describe(exc, last_ok, size, fh)
                    raise BagError(self.damage) from None
                last_ok = fh.tell()
                if isinstance(rec, Message):
                    topic, msg_type = channels[rec.channel_id]
                    self.topics[topic].seen(rec.log_time)
                    if wanted is None or topic in wanted:
                        yield BagMessage(topic, msg_type, rec.data, rec.log_time,
                                         rec.publish_time, rec.sequence)
                elif isinstance(rec, Channel):
                    if rec.id not in channels:
                        channels[rec.id] = (rec.topic, schemas.get(rec.schema_id, ''))
                        self.topics.setdefault(rec.topic, TopicInfo(
                            rec.topic, schemas.get(rec.schema_id, ''),
                            parse_qos_yaml(rec.metadata.get('offered_qos_profiles', '')),
                            rec.metadata.get('topic_type_hash', '')))
                elif isinstance(rec, Schema):
                    schemas[rec.id] = rec.name
                elif isinstance(rec, Header):
                    if rec.profile != 'ros2':
                        self.damage = (f'{self.file}: MCAP profile {rec.profile!r}, not '
                                       "'ros2': not a ROS 2 bag")
                        raise BagError(self.damage)
                elif isinstance(rec, Metadata) and rec.name == 'rosbag2':
                    pass
                elif isinstance(rec, Footer):
                    self.complete = True
        if not self.complete:
            self.damage = (f'{self.file}: ends after {size} bytes without the MCAP footer '
                           '(still being recorded, or the recorder crashed or was killed)')
            raise BagError(self.damage)

    def messages_by_time(self, topics: Iterable[str] | None = None,
                         window_ns: int = 2_000_000_000) -> Iterator[BagMessage]:
        """The messages in log-time order (as rosbag2 plays them), streaming: the file is in
        receive order up to one poll of the recorder, so a reorder window of ``window_ns`` of
        log time is enough. Damage raises :class:`BagError` after the messages before it."""
        heap: list[tuple[int, int, BagMessage]] = []
        k = 0
        try:
            for m in self.messages(topics):
                heapq.heappush(heap, (m.log_ns, k, m))
                k += 1
                while heap and heap[0][0] < m.log_ns - window_ns:
                    yield heapq.heappop(heap)[2]
        except BagError:
            while heap:
                yield heapq.heappop(heap)[2]
            raise
        while heap:
            yield heapq.heappop(heap)[2]

    def _describe(self, exc: Exception, offset: int, size: int, fh: Any) -> str:
        """``offset``: where the last good record ended."""
        what = type(exc).__name__ + (f': {exc}' if str(exc) else '')
        fh.seek(offset)
        head = fh.read(9)                    # opcode, uint64 length of the next record
        if len(head) < 9 or offset + 9 + int.from_bytes(head[1:], 'little') > size:
            what = 'EndOfFile' if offset < size else what
        if offset >= size:
            return (f'{self.file}: ends after {size} bytes without the MCAP footer (still '
                    'being recorded, or the recorder crashed or was killed); the messages '
                    'before are readable')
        if 'EndOfFile' in what:
            return (f'{self.file}: truncated: the file ends inside a record (bytes {offset} to '
                    f'{size}, {what}); the messages before it are readable')
        return (f'{self.file}: corrupt record after byte {offset} of {size} ({what}); the '
                'messages before it are readable')


@dataclass
class BagInfo:
    """What :func:`bag_info` found: the topics with their readable messages, and the damage."""

    file: Path
    size: int
    topics: dict[str, TopicInfo]
    damage: str | None
    custom_data: dict[str, str]

    @property
    def message_count(self) -> int:
        return sum(t.count for t in self.topics.values())

    @property
    def start_ns(self) -> int | None:
        firsts = [t.first_ns for t in self.topics.values() if t.first_ns is not None]
        return min(firsts) if firsts else None

    @property
    def end_ns(self) -> int | None:
        lasts = [t.last_ns for t in self.topics.values() if t.last_ns is not None]
        return max(lasts) if lasts else None

    @property
    def duration_s(self) -> float:
        s, e = self.start_ns, self.end_ns
        return 0.0 if s is None or e is None else (e - s) / 1e9


def bag_info(bag: str | os.PathLike) -> BagInfo:
    """Read the whole bag (CRCs checked); never raises on damage, reports it instead."""
    reader = BagReader(bag)
    try:
        for _ in reader.messages(topics=()):
            pass
    except BagError:
        pass
    return BagInfo(reader.file, reader.file.stat().st_size, reader.topics, reader.damage,
                   reader.custom_data)


def bag_topics(bag: str | os.PathLike) -> dict[str, TopicInfo]:
    """The topics of a bag (type, QoS, hash, count) from the MCAP summary, or by reading the
    whole file when it has none (a bag not finished: :func:`bag_info`)."""
    from mcap.reader import make_reader
    path = mcap_path(bag)
    try:
        with open(path, 'rb') as fh:
            summary = make_reader(fh).get_summary()
    except Exception:                                   # noqa: BLE001 no/damaged summary
        summary = None
    if summary is None or summary.statistics is None:
        return bag_info(bag).topics
    counts = summary.statistics.channel_message_counts
    out = {}
    for cid, ch in summary.channels.items():
        schema = summary.schemas.get(ch.schema_id)
        out[ch.topic] = TopicInfo(ch.topic, schema.name if schema else '',
                                  parse_qos_yaml(ch.metadata.get('offered_qos_profiles', '')),
                                  ch.metadata.get('topic_type_hash', ''), int(counts.get(cid, 0)))
    return out


def format_info(info: BagInfo) -> str:
    """``ros2 bag info``-like text."""
    def stamp(ns: int | None) -> str:
        if ns is None:
            return '-'
        return time.strftime('%Y-%m-%d %H:%M:%S', time.localtime(ns / 1e9)) + \
            f'.{ns % 1_000_000_000:09d} ({ns // 1_000_000_000}.{ns % 1_000_000_000:09d})'

    lines = [f'Files:             {info.file.name}',
             f'Bag size:          {_size(info.size)}',
             'Storage id:        mcap',
             f'Duration:          {info.duration_s:.9f}s',
             f'Start:             {stamp(info.start_ns)}',
             f'End:               {stamp(info.end_ns)}',
             f'Messages:          {info.message_count}']
    width = max((len(t) for t in info.topics), default=0)
    for k, t in enumerate(sorted(info.topics.values(), key=lambda t: t.name)):
        head = 'Topic information: ' if k == 0 else ' ' * 19
        qos = t.qos_profiles[0] if t.qos_profiles else {}
        lines.append(f'{head}Topic: {t.name:<{width}} | Type: {t.type} | Count: {t.count} | '
                     f'Serialization Format: cdr | QoS: {qos.get("reliability", "?")}, '
                     f'{qos.get("durability", "?")}, depth {qos.get("depth", "?")}')
    if info.custom_data:
        lines.append('Custom data:       ' + ', '.join(f'{k}={v}'
                                                     for k, v in info.custom_data.items()))
    if info.damage:
        lines.append(f'DAMAGED:           {info.damage}')
        lines.append(f'Readable:          {info.message_count} messages, '
                     f'{info.duration_s:.3f} s (everything before the damage)')
    return '\n'.join(lines)


def _size(n: int) -> str:
    for unit in ('B', 'KiB', 'MiB', 'GiB'):
        if n < 1024 or unit == 'GiB':
            return f'{n:.1f} {unit}' if unit != 'B' else f'{n} B'
        n /= 1024
    return f'{n} B'
