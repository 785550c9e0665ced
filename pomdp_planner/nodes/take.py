"""Taking a sample with its writer and its size, before anything is copied into Python, in a
thread of the node's own: the node's input reader.

rclpy 7.1.6 (the Jazzy wheel) hands a subscription callback the message and a ``MessageInfo``
with timestamps and sequence numbers only: not the publisher's GID, which the rule "One writer"
(``core/loop/writers.py``) needs. rcl has it: ``rcl_take_serialized_message`` fills an
``rmw_message_info_t`` with ``publisher_gid`` next to the serialized sample. :class:`SampleTake`
calls it through ``ctypes`` on the library instance rclpy itself loaded (the same ``librcl.so``,
found in ``/proc/self/maps``), with the struct layouts of rmw/rcutils for Jazzy
(``RMW_GID_STORAGE_SIZE`` 16). The sample's size is known before it is copied: a sample larger
than the subscription's bound is dropped unread (its buffer shrunk again at once) and the callback
gets ``None`` for it.

A subscription made with :func:`subscribe` is a *raw* one (the callback gets the serialized
bytes and a dict with ``"publisher_gid"`` (hex) and ``"size"``). It may have a
``screen(raw, info) -> bool`` (the node's size and writer rules). Such subscriptions are served by
the node's :class:`InputReader`, not by the executor: one thread per node waits on them alone (an
rcl wait set of those subscriptions, the GIL released while it waits), takes each sample as it
comes, screens it there, and hands only the samples the screen passes to the executor (a guard
condition in the subscription's callback group, ``info["screened"]`` set), where the callback
runs as any callback would. So a flood of foreign or oversized samples costs the node a wake-up
of that thread, a ``ctypes`` call and a dictionary look-up each, and never an executor cycle (which
costs about half a millisecond with rclpy 7.1.6, as many as a node's timers and services).
If the library cannot be found, :data:`AVAILABLE` is false and every raw subscription is taken
the stock way by the executor (bytes, no writer: the samples are *unattributed*, and the size is
checked after the copy). ``test/test_nodes_bad_input.py`` checks that the GID matches the
graph's ``endpoint_gid`` of the writer.
"""

from __future__ import annotations

import atexit
import ctypes
import threading
import weakref
from collections import deque
from collections.abc import Callable
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path

from rclpy.callback_groups import CallbackGroup
from rclpy.exceptions import InvalidHandle
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy_impl
from rclpy.node import Node
from rclpy.qos import QoSProfile
from rclpy.subscription import Subscription

#: Buffer kept between takes (bytes); a larger sample grows it for one take only.
SMALL_BUFFER = 4096
#: Samples the reader takes from one subscription before it looks at the others again.
DRAIN = 256
_GID_SIZE = 16  # RMW_GID_STORAGE_SIZE (Jazzy)
_RCL_RET_OK = 0


class _Allocator(ctypes.Structure):
    _fields_ = [("allocate", ctypes.c_void_p), ("deallocate", ctypes.c_void_p), ("reallocate", ctypes.c_void_p),
                ("zero_allocate", ctypes.c_void_p), ("state", ctypes.c_void_p)]


class _Uint8Array(ctypes.Structure):  # rcutils_uint8_array_t = rcl_serialized_message_t
    _fields_ = [("buffer", ctypes.POINTER(ctypes.c_uint8)), ("buffer_length", ctypes.c_size_t),
                ("buffer_capacity", ctypes.c_size_t), ("allocator", _Allocator)]


class _Gid(ctypes.Structure):
    _fields_ = [("implementation_identifier", ctypes.c_char_p), ("data", ctypes.c_uint8 * _GID_SIZE)]


class _MessageInfo(ctypes.Structure):  # rmw_message_info_t
    _fields_ = [("source_timestamp", ctypes.c_int64), ("received_timestamp", ctypes.c_int64),
                ("publication_sequence_number", ctypes.c_uint64), ("reception_sequence_number", ctypes.c_uint64),
                ("publisher_gid", _Gid), ("from_intra_process", ctypes.c_bool)]


def _loaded(name: str) -> ctypes.CDLL | None:
    """The instance of library ``name`` this process has loaded (rclpy's), or ``None``."""
    try:
        maps = Path("/proc/self/maps").read_text()
    except OSError:
        return None
    for line in maps.splitlines():
        path = line.split()[-1] if line.split() else ""
        if path.endswith("/" + name):
            return ctypes.CDLL(path)
    return None


def _bind():
    _rclpy_impl.Subscription  # noqa: B018 - rclpy's extension, and with it librcl, is loaded now
    rcl, rcutils = _loaded("librcl.so"), _loaded("librcutils.so")
    if rcl is None or rcutils is None:
        return None
    rcutils.rcutils_get_default_allocator.restype = _Allocator
    rcutils.rcutils_uint8_array_init.argtypes = [ctypes.POINTER(_Uint8Array), ctypes.c_size_t,
                                                 ctypes.POINTER(_Allocator)]
    rcutils.rcutils_uint8_array_fini.argtypes = [ctypes.POINTER(_Uint8Array)]
    rcutils.rcutils_uint8_array_resize.argtypes = [ctypes.POINTER(_Uint8Array), ctypes.c_size_t]
    rcl.rcl_take_serialized_message.argtypes = [ctypes.c_void_p, ctypes.POINTER(_Uint8Array),
                                                ctypes.POINTER(_MessageInfo), ctypes.c_void_p]
    rcl.rcl_take_serialized_message.restype = ctypes.c_int32
    return rcl, rcutils


_LIBS = _bind()
#: Whether samples can be taken with their writer (else every executor takes the stock way).
AVAILABLE = _LIBS is not None


class SampleTake:
    """Takes the samples of ``sub`` (a raw subscription) with their writer and size; a sample larger
    than ``max_bytes`` is not copied."""

    def __init__(self, sub: Subscription, max_bytes: int):
        rcl, rcutils = _LIBS
        self._rcl, self._rcutils = rcl, rcutils
        self.sub = sub
        self.max_bytes = max_bytes
        self._buf = _Uint8Array()
        self._info = _MessageInfo()
        allocator = rcutils.rcutils_get_default_allocator()
        if rcutils.rcutils_uint8_array_init(ctypes.byref(self._buf), SMALL_BUFFER, ctypes.byref(allocator)) != 0:
            raise MemoryError("cannot allocate the serialized-message buffer")

    def take(self) -> tuple[bytes | None, dict] | None:
        """``(serialized bytes or None if too large, info)`` of the next sample, or ``None`` if there
        is none. Called with the subscription's handle held (:class:`InputReader`)."""
        ret = self._rcl.rcl_take_serialized_message(self.sub.handle.pointer, ctypes.byref(self._buf),
                                                    ctypes.byref(self._info), None)
        if ret != _RCL_RET_OK:
            return None
        size = int(self._buf.buffer_length)
        info = {"source_timestamp": self._info.source_timestamp,
                "received_timestamp": self._info.received_timestamp,
                "publication_sequence_number": self._info.publication_sequence_number,
                "publisher_gid": bytes(self._info.publisher_gid.data).hex(), "size": size}
        if size > self.max_bytes:
            if self._buf.buffer_capacity > SMALL_BUFFER:
                self._rcutils.rcutils_uint8_array_resize(ctypes.byref(self._buf), SMALL_BUFFER)
            return None, info
        return ctypes.string_at(self._buf.buffer, size), info

    def __del__(self):
        try:
            self._rcutils.rcutils_uint8_array_fini(ctypes.byref(self._buf))
        except Exception:  # interpreter shutdown
            pass


class _Reader(CallbackGroup):
    """The callback group of the subscriptions an :class:`InputReader` serves: the executor never
    waits on them."""

    def can_execute(self, entity) -> bool:
        return False

    def beginning_execution(self, entity) -> bool:
        return False

    def ending_execution(self, entity) -> None:
        pass


@dataclass(eq=False)
class _Entry:
    sub: Subscription
    take: SampleTake
    screen: Callable[[bytes | None, dict], bool] | None
    callback: Callable[[bytes | None, dict], None]
    queue: deque
    guard: object = None


class InputReader:
    """The thread that takes the samples of ``node``'s raw subscriptions (module docstring).

    It waits at most :attr:`PERIOD` seconds at a time, so a new subscription is served and a
    destroyed one forgotten within that time, and it ends with the node's context. A sample
    the screen passes waits in its subscription's queue (as deep as the subscription's history)
    until the executor runs the callback."""

    PERIOD = 0.1

    def __init__(self, node: Node):
        self.node = node
        self.context = node.context
        self._entries: list[_Entry] = []
        self._lock = threading.Lock()
        self._stop = threading.Event()
        with self.context.handle:
            self._wake = _rclpy_impl.GuardCondition(self.context.handle)
        self._thread = threading.Thread(target=self._run, name=f"input reader of {node.get_name()}", daemon=True)
        _READERS.add(self)
        self._thread.start()

    @classmethod
    def of(cls, node: Node) -> InputReader:
        """The input reader of ``node`` (made with its first raw subscription)."""
        reader = getattr(node, "_input_reader", None)
        if reader is None:
            reader = node._input_reader = cls(node)
        return reader

    @staticmethod
    def close_of(node: Node) -> None:
        """End the input reader of ``node``, if it has one (before the node is destroyed)."""
        reader = getattr(node, "_input_reader", None)
        if reader is not None:
            reader.close()

    def close(self) -> None:
        """End the thread: woken at once, joined (a thread still in a wait when the interpreter
        finalizes aborts the process)."""
        self._stop.set()
        try:
            self._wake.trigger_guard_condition()
        except Exception:  # the context is gone: the wait ends within PERIOD
            pass
        if threading.current_thread() is not self._thread:
            self._thread.join(timeout=2.0)
        _READERS.discard(self)

    def add(self, sub: Subscription, take: SampleTake, screen, callback, group, depth: int) -> None:
        entry = _Entry(sub, take, screen, callback, deque(maxlen=max(1, depth)))
        entry.guard = self.node.create_guard_condition(lambda: self._deliver(entry), callback_group=group)
        with self._lock:
            self._entries.append(entry)

    @staticmethod
    def _deliver(entry: _Entry) -> None:
        """The guard's callback, in the executor: the samples that passed the screen, in order."""
        while entry.queue:
            raw, info = entry.queue.popleft()
            entry.callback(raw, info)

    def _forget(self, entry: _Entry) -> None:
        with self._lock:
            if entry in self._entries:
                self._entries.remove(entry)

    def _run(self) -> None:
        while self.context.ok() and not self._stop.is_set():
            with self._lock:
                entries = list(self._entries)
            try:
                if not self._wait_and_take(entries):
                    self._stop.wait(self.PERIOD)
            except Exception as exc:  # a bug: said, and the reader goes on
                if not self.context.ok() or self._stop.is_set():
                    return
                self.node.get_logger().error(f"input reader: {exc!r}")
                self._stop.wait(self.PERIOD)

    def _wait_and_take(self, entries: list[_Entry]) -> bool:
        """Wait on ``entries`` once and take what is ready; ``False`` if there is nothing to wait on."""
        with ExitStack() as stack:
            live = []
            for e in entries:
                try:
                    stack.enter_context(e.sub.handle)
                    live.append(e)
                except InvalidHandle:  # destroyed (a managed node's cleanup)
                    self._forget(e)
            if not live or self._stop.is_set():
                return False
            try:
                stack.enter_context(self.context.handle)
            except InvalidHandle:
                return True
            wait_set = _rclpy_impl.WaitSet(len(live), 1, 0, 0, 0, 0, self.context.handle)
            wait_set.clear_entities()
            for e in live:
                wait_set.add_subscription(e.sub.handle)
            wait_set.add_guard_condition(self._wake)
            wait_set.wait(int(self.PERIOD * 1e9))
            ready = set(wait_set.get_ready_entities("subscription"))
            for e in live:
                if e.sub.handle.pointer in ready:
                    self._drain(e)
        return True

    def _drain(self, e: _Entry) -> None:
        """Take up to :data:`DRAIN` samples of ``e``; queue those the screen passes and wake the executor."""
        passed = False
        for _ in range(DRAIN):
            got = e.take.take()
            if got is None:
                break
            if e.screen is None or e.screen(*got):
                got[1]["screened"] = True
                e.queue.append(got)
                passed = True
        if passed:
            try:
                e.guard.trigger()
            except InvalidHandle:  # destroyed with its subscription
                self._forget(e)


#: The one callback group of every served subscription.
_READER_GROUP = _Reader()
#: Every input reader of this process, ended before the interpreter finalizes.
_READERS: weakref.WeakSet[InputReader] = weakref.WeakSet()


@atexit.register
def _close_readers() -> None:
    for reader in list(_READERS):
        reader.close()


def subscribe(node: Node, msg_type, topic: str, callback: Callable[[bytes | None, dict], None], qos: QoSProfile,
              max_bytes: int, *, screen: Callable[[bytes | None, dict], bool] | None = None,
              callback_group=None) -> Subscription:
    """A raw subscription of ``node`` served by its :class:`InputReader` (module docstring):
    ``callback(serialized or None, info)`` runs in ``callback_group`` (default: the node's);
    ``None`` for a sample larger than ``max_bytes``; ``screen`` decides in the reader which
    samples reach the callback."""
    if not AVAILABLE:
        return node.create_subscription(msg_type, topic, callback, qos, raw=True, callback_group=callback_group)
    sub = node.create_subscription(msg_type, topic, callback, qos, raw=True, callback_group=_READER_GROUP)
    depth = getattr(qos, "depth", 10) or 10
    InputReader.of(node).add(sub, SampleTake(sub, max_bytes), screen, callback,
                             callback_group or node.default_callback_group, depth)
    return sub
