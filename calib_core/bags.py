"""MCAP bags in rosbag2 layout (metadata.yaml version 9, ``<name>_0.mcap``, profile ros2,
schema encoding ros2msg, CDR messages), written and read with the ``rosbags`` package so a
real ``ros2 bag play``, ``rosbags`` and ``mcap-ros2-support`` can all read them.

Messages go in and out as CDR bytes: nodes serialise with rclpy, offline code decodes with
the bag's own embedded definitions. No rclpy here.

A bag survives its writer being killed: the MCAP writer keeps messages in memory until it
closes, so every message is also appended, flushed, to a journal ``<name>.journal`` in the
bag directory, which is removed when the bag is complete. A bag without metadata.yaml
but with a journal is a cut run; :func:`read_bag` then reads the journal, up to its last
complete record (:func:`cut_run_count` says how many messages that is).
"""
from __future__ import annotations

import os
import struct
import sys
from pathlib import Path
from typing import Iterator

from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from calib_core.errors import BagError

PROJECT_PACKAGES = ('alignment_msgs',)
JOURNAL_MAGIC = b'machine_alignment journal 1\n'
# Per record: topic length, message type length (u16), stamp (ns, u64), data length (u32).
_RECORD = struct.Struct('<HHQI')


def _interface_dirs(package: str) -> list[Path]:
    """Where ``package``'s .msg/.srv files are: the source tree first, then install prefixes."""
    here = Path(__file__).resolve().parents[1] / 'interfaces' / package
    candidates = [here]
    prefixes = os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep) + [sys.prefix]
    candidates += [Path(p) / 'share' / package for p in prefixes if p]
    return [c for c in candidates if (c / 'msg').is_dir()]


def project_typestore():
    """A rosbags typestore with ROS 2 Jazzy's standard types and this project's messages."""
    store = get_typestore(Stores.ROS2_JAZZY)
    for package in PROJECT_PACKAGES:
        dirs = _interface_dirs(package)
        if not dirs:
            raise BagError(f'cannot find the message definitions of {package}')
        types = {}
        for path in sorted((dirs[0] / 'msg').glob('*.msg')):
            types.update(get_types_from_msg(path.read_text(), f'{package}/msg/{path.stem}'))
        store.register(types)
    return store


class BagWriter:
    """Writes CDR-serialised messages to a new rosbag2 MCAP bag directory.

    Use as a context manager; the bag is complete (metadata.yaml written) on exit."""

    def __init__(self, path: str | os.PathLike):
        path = Path(path)
        if path.exists():
            raise BagError(f'{path} exists already; a bag is never overwritten')
        path.parent.mkdir(parents=True, exist_ok=True)
        self.path = path
        self._typestore = project_typestore()
        self._writer = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
        self._connections = {}
        self._msgtypes = {}
        self._journal = None

    def __enter__(self) -> 'BagWriter':
        self._writer.open()
        self._journal = open(self.path / f'{self.path.name}.journal', 'xb')
        self._journal.write(JOURNAL_MAGIC)
        self._journal.flush()
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        if self._writer is None:
            return
        self._writer.close()
        self._writer = None
        # rosbags names the file <bag>.mcap; rosbag2 (and this suite's contract) <bag>_0.mcap.
        old, new = f'{self.path.name}.mcap', f'{self.path.name}_0.mcap'
        (self.path / old).rename(self.path / new)
        metadata = self.path / 'metadata.yaml'
        metadata.write_text(metadata.read_text().replace(f' {old}\n', f' {new}\n'))
        if self._journal is not None:   # the bag is complete: the journal is not needed
            self._journal.close()
            Path(self._journal.name).unlink()
            self._journal = None

    def add_topic(self, topic: str, msgtype: str) -> None:
        """Declare ``topic`` with ROS type ``msgtype`` (``pkg/msg/Name``)."""
        if topic in self._connections:
            return
        if msgtype not in self._typestore.fielddefs:
            raise BagError(f'unknown message type {msgtype}')
        self._connections[topic] = self._writer.add_connection(
            topic, msgtype, typestore=self._typestore)
        self._msgtypes[topic] = msgtype

    def write(self, topic: str, stamp_ns: int, cdr: bytes) -> None:
        """Append one CDR message received at ``stamp_ns`` (ns since the epoch)."""
        if topic not in self._connections:
            raise BagError(f'topic {topic} was not declared with add_topic')
        self._writer.write(self._connections[topic], int(stamp_ns), cdr)
        if self._journal is not None:
            name, msgtype = topic.encode(), self._msgtypes[topic].encode()
            self._journal.write(_RECORD.pack(len(name), len(msgtype), int(stamp_ns), len(cdr))
                                + name + msgtype + bytes(cdr))
            self._journal.flush()   # in the OS's hands: survives the process being killed


def _journal(path: Path) -> Path | None:
    """The journal of a cut run in bag directory ``path`` (no metadata.yaml), or None."""
    journal = path / f'{path.name}.journal'
    if path.is_dir() and not (path / 'metadata.yaml').exists() and journal.is_file():
        return journal
    return None


def _journal_records(journal: Path) -> Iterator[tuple[str, str, int, bytes]]:
    """``(topic, msgtype, stamp_ns, cdr)`` of every complete record; a record cut by the
    kill is left out."""
    data = journal.read_bytes()
    if not data.startswith(JOURNAL_MAGIC):
        raise BagError(f'{journal} is not a machine_alignment journal')
    at = len(JOURNAL_MAGIC)
    while at + _RECORD.size <= len(data):
        name_length, type_length, stamp, size = _RECORD.unpack_from(data, at)
        start = at + _RECORD.size
        end = start + name_length + type_length + size
        if end > len(data):
            return
        try:
            topic = data[start:start + name_length].decode()
            msgtype = data[start + name_length:start + name_length + type_length].decode()
        except UnicodeDecodeError:   # damaged from here on: what came before stands
            return
        yield topic, msgtype, stamp, data[start + name_length + type_length:end]
        at = end


def cut_run_count(path: str | os.PathLike, topic: str | None = None) -> int | None:
    """How many messages (on ``topic``, else on any) a cut run's journal holds, or None if
    ``path`` is a complete bag."""
    journal = _journal(Path(path))
    if journal is None:
        return None
    return sum(1 for recorded, *_ in _journal_records(journal) if topic in (None, recorded))


def recover_cut_run(path: str | os.PathLike, out: str | os.PathLike | None = None) -> Path:
    """Write a cut run's journal (bag directory ``path``) as a complete bag ``out``
    (default ``<path>_recovered``), which any MCAP or rosbag2 tool opens (Foxglove, ``ros2
    bag``). The cut run is left as it is. Returns ``out``.

    Raises
    ------
    BagError
        ``path`` is not a cut run, it holds no complete message, or ``out`` exists."""
    path = Path(path)
    journal = _journal(path)
    if journal is None:
        raise BagError(f'{path} is not a cut run (it has metadata.yaml, or no journal): '
                       'nothing to recover')
    records = list(_journal_records(journal))
    if not records:
        raise BagError(f'{path} was cut before its first message: nothing to recover')
    out = Path(out) if out is not None else path.with_name(f'{path.name}_recovered')
    with BagWriter(out) as bag:
        for topic, msgtype, _, _ in records:
            bag.add_topic(topic, msgtype)
        for topic, _, stamp, cdr in records:
            bag.write(topic, stamp, cdr)
    return out


def _require_bag(path: Path) -> None:
    """BagError unless ``path`` is a rosbag2 bag directory (or an existing bag file)."""
    if not path.exists():
        raise BagError(f'no bag at {path}')
    if path.is_dir() and not (path / 'metadata.yaml').exists():
        raise BagError(f'{path} is not a rosbag2 bag: metadata.yaml is missing (and no '
                       'journal of a cut run)')


def _unreadable(path: Path, exc: Exception) -> BagError:
    # rosbags raises several exception types for damaged or foreign files.
    return BagError(f'cannot read bag {path}: {exc} (truncated or not a rosbag2 bag?)')


def read_bag(path: str | os.PathLike, topics: list[str] | None = None
             ) -> Iterator[tuple[str, str, int, bytes]]:
    """Yield ``(topic, msgtype, stamp_ns, cdr_bytes)`` from a rosbag2 bag in time order.

    Raises
    ------
    BagError
        Missing, truncated or foreign bag.
    """
    path = Path(path)
    journal = _journal(path)
    if journal is not None:
        for record in _journal_records(journal):
            if topics is None or record[0] in topics:
                yield record
        return
    _require_bag(path)
    try:
        with AnyReader([path]) as reader:
            connections = [c for c in reader.connections if topics is None or c.topic in topics]
            for connection, stamp, raw in reader.messages(connections=connections):
                yield connection.topic, connection.msgtype, stamp, bytes(raw)
    except Exception as exc:
        raise _unreadable(path, exc) from exc


def bag_topics(path: str | os.PathLike) -> dict[str, str]:
    """``{topic: msgtype}`` of a rosbag2 bag, from its metadata and file summary."""
    path = Path(path)
    journal = _journal(path)
    if journal is not None:
        return {topic: msgtype for topic, msgtype, _, _ in _journal_records(journal)}
    _require_bag(path)
    try:
        with AnyReader([path]) as reader:
            return {c.topic: c.msgtype for c in reader.connections}
    except Exception as exc:
        raise _unreadable(path, exc) from exc


def decode_bag(path: str | os.PathLike, topics: list[str] | None = None
               ) -> Iterator[tuple[str, int, object]]:
    """Yield ``(topic, stamp_ns, message)`` with messages decoded from the bag's own
    embedded definitions (attribute access like rclpy messages)."""
    path = Path(path)
    store = project_typestore()
    for topic, msgtype, stamp, raw in read_bag(path, topics):
        try:
            yield topic, stamp, store.deserialize_cdr(raw, msgtype)
        except Exception as exc:
            raise BagError(f'cannot decode a {msgtype} message on {topic} in {path}: {exc}') from exc
