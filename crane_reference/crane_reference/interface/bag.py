"""rosbag2 bags without ROS: :class:`BagWriter`.

:class:`BagWriter` wraps ``rosbags.rosbag2.Writer``: MCAP or SQLite 3 storage, metadata version 9
(Jazzy, the default) or 8 (Humble reads it), every topic registered with its message definition and
RIHS01 type hash from rosbags' ROS 2 Jazzy typestore (the hashes equal the message packages'
``share/<pkg>/msg/<Msg>.json``), this project's action types among them, and the offered QoS profiles.
Messages are written already serialized (CDR), with a timestamp in integer nanoseconds.  The live recorder
(:mod:`crane_reference.ros.recorder`) and the offline export (:mod:`.reference_bag`) use it; it needs no ROS
installation.
"""
from __future__ import annotations

import queue
import threading
from collections.abc import Callable, Iterable
from concurrent.futures import Future
from functools import partial
from pathlib import Path
from types import TracebackType
from typing import Any

from rosbags.interfaces import Connection, Qos, QosTime
from rosbags.rosbag2 import StoragePlugin, Writer, WriterError
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from .messages import STORAGES

VERSIONS = (9, 8)
QUEUE_SIZE = 100_000  # messages waiting for the writer thread before write() blocks
INFINITE = QosTime(sec=9223372036, nsec=854775807)  # RMW_DURATION_INFINITE as rosbag2 writes it


class BagError(RuntimeError):
    """A bag that cannot be written as asked (existing path, unknown storage or type, closed bag...)."""


INTERFACES = "crane_reference_interfaces"
ACTION = "Retarget"


def interface_definitions() -> dict[str, tuple[str, tuple[str, ...]]]:
    """The message types of this project's interface package that go on topics, from its ``.action`` file (the
    installed one, else the source tree's; none if neither is there): the action's goal, result and feedback and
    the feedback message of ``~/retarget/_action/feedback``, as rosidl generates them, each with its ``.msg`` text
    and the types it nests, in order."""
    relative = Path("action") / f"{ACTION}.action"
    try:
        from ament_index_python.packages import get_package_share_directory

        path = Path(get_package_share_directory(INTERFACES)) / relative
    except (ImportError, LookupError, OSError):
        path = Path(__file__).resolve().parents[3] / INTERFACES / relative
    if not path.is_file():
        return {}
    goal, result, feedback = path.read_text(encoding="utf-8").split("\n---\n")
    prefix = f"{INTERFACES}/action/{ACTION}"
    time = "builtin_interfaces/msg/Time"
    return {f"{prefix}_Goal": (goal, ()), f"{prefix}_Result": (result, (time,)),
            f"{prefix}_Feedback": (feedback, (time,)),
            f"{prefix}_FeedbackMessage": (f"unique_identifier_msgs/UUID goal_id\n{prefix}_Feedback feedback",
                                          ("unique_identifier_msgs/msg/UUID", f"{prefix}_Feedback", time))}


def interface_types() -> dict[str, Any]:
    """rosbags' types of :func:`interface_definitions` (their RIHS01 hashes are rosidl's)."""
    types: dict[str, Any] = {}
    for name, (text, _) in interface_definitions().items():
        types.update(get_types_from_msg(text, name))
    return types


def message_definition(typestore: Any, msgtype: str) -> str:
    """The message definition rosbag2 stores for ``msgtype`` (its ``.msg`` text, then each nested type's after a
    line of '=' and ``MSG: name``); rosbags' own for the message packages, written here for the action types,
    whose nested action types rosbags does not name."""
    definitions = interface_definitions()
    if msgtype not in definitions:
        return typestore.generate_msgdef(msgtype, ros_version=2)[0]
    text, nested = definitions[msgtype]
    parts = [text]
    for name in nested:
        body = definitions[name][0] if name in definitions else typestore.generate_msgdef(name, ros_version=2)[0]
        parts.append(f"{'=' * 80}\nMSG: {name.replace('/msg/', '/')}\n{body}")
    return "\n".join(parts)


def jazzy_typestore() -> Any:
    """rosbags' typestore of ROS 2 Jazzy, with this project's interface types (:func:`interface_types`)."""
    typestore = get_typestore(Stores.ROS2_JAZZY)
    typestore.register(interface_types())
    return typestore


def directory_size(path: Path) -> int:
    """Bytes in the files directly inside ``path`` (0 if it does not exist)."""
    return sum(f.stat().st_size for f in path.iterdir() if f.is_file()) if path.is_dir() else 0


class BagWriter:
    """A rosbag2 bag being written: topics added by name, type and offered QoS; serialized messages
    written with a timestamp in nanoseconds.

    Thread-safe: every storage operation runs on one writer thread of its own (SQLite connections
    belong to the thread that made them), so :meth:`write` only queues the message and never waits on
    the disk unless :data:`QUEUE_SIZE` messages are pending.  A context manager that closes the bag on
    exit, also after an exception (what was written stays readable).
    """

    def __init__(self, path: Path | str, storage: str = "mcap", version: int = 9, typestore: Any = None) -> None:
        """Create the bag directory ``path`` (which must not exist) and open the storage.

        ``storage`` is one of :data:`STORAGES`, ``version`` the metadata version (9: Jazzy, 8: Humble);
        ``typestore`` defaults to rosbags' Jazzy typestore.  Raises :class:`BagError`.
        """
        if storage not in STORAGES:
            raise BagError(f"storage {storage!r}: must be one of {', '.join(STORAGES)}")
        if version not in VERSIONS:
            raise BagError(f"bag version {version!r}: must be 9 (Jazzy) or 8 (Humble)")
        self.path = Path(path)
        if self.path.exists():
            raise BagError(f"{self.path} exists already: give a new directory for the bag")
        self.storage, self.version = storage, version
        self.typestore = typestore if typestore is not None else jazzy_typestore()
        self._writer = Writer(self.path, version=version, storage_plugin=StoragePlugin[storage.upper()])
        self._connections: dict[str, Connection] = {}
        self._types: dict[str, str] = {}
        self.counts: dict[str, int] = {}  # messages given to write() per topic
        self.first_ns: int | None = None  # the earliest and latest timestamps written
        self.last_ns: int | None = None
        self._lock = threading.Lock()
        self._requests: queue.Queue[tuple[Callable[..., Any], tuple, Future | None] | None] = queue.Queue(QUEUE_SIZE)
        self._failure: BaseException | None = None
        self._thread = threading.Thread(target=self._serve, name=f"bag writer {self.path.name}", daemon=True)
        self._thread.start()
        self._open = True
        try:
            self._call(self._writer.open)
        except (WriterError, OSError) as error:
            self._stop()
            raise BagError(f"cannot create the bag {self.path}: {error}") from error

    def _serve(self) -> None:
        """Writer thread: run the queued storage operations in order until the stop request (None)."""
        while (request := self._requests.get()) is not None:
            function, args, future = request
            try:
                result = function(*args)
            except BaseException as error:  # reported to the caller, or at the next write / close
                if future is not None:
                    future.set_exception(error)
                elif self._failure is None:
                    self._failure = error
            else:
                if future is not None:
                    future.set_result(result)

    def _call(self, function: Callable[..., Any], *args: Any) -> Any:
        """Run ``function(*args)`` on the writer thread after every queued operation; its result."""
        future: Future = Future()
        self._requests.put((function, args, future))
        return future.result()

    def _stop(self) -> None:
        self._open = False
        self._requests.put(None)
        self._thread.join()

    def add_topic(self, name: str, msgtype: str, qos: Iterable[Qos] = ()) -> None:
        """Register topic ``name`` of type ``msgtype`` (e.g. ``sensor_msgs/msg/JointState``) with the QoS
        profiles its publishers offer.  Raises :class:`BagError` for an unknown type or a topic added twice."""
        if msgtype not in self.typestore.types:
            raise BagError(f"{name}: type {msgtype} is not in the typestore, its definition is unknown")
        with self._lock:
            self._check_open()
            if name in self._connections:
                raise BagError(f"topic {name} is in the bag already")
            self._connections[name] = self._call(partial(
                self._writer.add_connection, msgdef=message_definition(self.typestore, msgtype),
                rihs01=self.typestore.hash_rihs01(msgtype), serialization_format="cdr",
                offered_qos_profiles=list(qos)), name, msgtype)
            self._types[name] = msgtype
            self.counts[name] = 0

    def write(self, name: str, data: bytes | memoryview, stamp_ns: int) -> None:
        """Queue one serialized (CDR) message of topic ``name`` with timestamp ``stamp_ns`` for writing.
        Raises :class:`BagError` if an earlier write failed."""
        with self._lock:
            self._check_open()
            connection = self._connections.get(name)
            if connection is None:
                raise BagError(f"topic {name} was not added to the bag")
            self._requests.put((self._writer.write, (connection, stamp_ns, bytes(data)), None))
            self.counts[name] += 1
            self.first_ns = stamp_ns if self.first_ns is None else min(self.first_ns, stamp_ns)
            self.last_ns = stamp_ns if self.last_ns is None else max(self.last_ns, stamp_ns)

    def write_message(self, name: str, message: Any, stamp_ns: int) -> None:
        """Serialize a message of the typestore's classes (rosbags) and write it."""
        self.write(name, self.typestore.serialize_cdr(message, self._types[name]), stamp_ns)

    @property
    def duration(self) -> float:
        """[s] from the first message's timestamp to the last's (as metadata.yaml gives it; 0 without messages)."""
        return 0.0 if self.first_ns is None else (self.last_ns - self.first_ns) / 1e9

    def size(self) -> int:
        """Bytes of the bag on disk so far (messages still queued or in the storage's open chunk excluded)."""
        return directory_size(self.path)

    def close(self) -> None:
        """Write every queued message, the indexes and metadata.yaml, and stop the writer thread; the bag
        is complete afterwards.  Idempotent.  Raises :class:`BagError` if a write had failed (the bag is
        closed all the same, with the messages written before the failure)."""
        with self._lock:
            if not self._open:
                return
            try:
                self._call(self._writer.close)
            finally:
                self._stop()
            if self._failure is not None:
                raise BagError(f"writing to {self.path} failed: {self._failure}") from self._failure

    def _check_open(self) -> None:
        if not self._open:
            raise BagError(f"the bag {self.path} is closed")
        if self._failure is not None:
            raise BagError(f"writing to {self.path} failed: {self._failure}") from self._failure

    def __enter__(self) -> BagWriter:
        return self

    def __exit__(self, kind: type[BaseException] | None, error: BaseException | None,
                 traceback: TracebackType | None) -> None:
        self.close()
