"""Taking a sample with its writer and its size, before anything is copied into Python.

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
bytes and a dict). The project's executor (:class:`TakeWithWriter`, mixed into
``NodeExecutor``) takes it through :class:`SampleTake` and adds ``"publisher_gid"`` (hex) and
``"size"`` to the dict; any other executor takes it the stock way (bytes, no writer: the
samples are *unattributed*, and the size is checked after the copy). A subscription may have a
``screen(raw, info) -> bool`` (the node's size and writer rules): the project's executor then
calls it as each sample is taken, drains up to :data:`DRAIN` samples in one go while the screen
drops them (a flood of foreign samples costs a ``ctypes`` call and a dictionary look-up each,
not an executor task), and runs the callback only for a sample the screen passes, with
``info["screened"]`` set; with any other executor the callback gets every sample and screens it.
If the library cannot be found, :data:`AVAILABLE` is false and every executor takes the stock
way. ``test/test_nodes_take.py`` checks that the GID matches the graph's ``endpoint_gid`` of the
writer.
"""

from __future__ import annotations

import ctypes
from collections.abc import Callable
from pathlib import Path

from rclpy.exceptions import InvalidHandle
from rclpy.executors import await_or_execute
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy_impl
from rclpy.node import Node
from rclpy.qos import QoSProfile
from rclpy.subscription import Subscription

#: Buffer kept between takes (bytes); a larger sample grows it for one take only.
SMALL_BUFFER = 4096
#: Samples a screened subscription drains in one take while its screen drops them (then the
#: executor serves the other entities before it comes back).
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
        is none. Called with the subscription's handle held (:class:`TakeWithWriter`)."""
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


def subscribe(node: Node, msg_type, topic: str, callback: Callable[[bytes | None, dict], None], qos: QoSProfile,
              max_bytes: int, *, screen: Callable[[bytes | None, dict], bool] | None = None,
              **kwargs) -> Subscription:
    """A raw subscription of ``node`` whose samples :class:`TakeWithWriter` takes with their writer;
    ``callback(serialized or None, info)``: ``None`` for a sample larger than ``max_bytes``;
    ``screen``: see the module docstring."""
    sub = node.create_subscription(msg_type, topic, callback, qos, raw=True, **kwargs)
    if AVAILABLE:
        sub.sample_take = SampleTake(sub, max_bytes)
        sub.screen = screen
    return sub


class TakeWithWriter:
    """Executor mixin: a subscription made with :func:`subscribe` is taken by its :class:`SampleTake`
    (rclpy 7.1.6's ``Executor._take_subscription``, private, is what it replaces for those)."""

    def _take_subscription(self, sub):
        take = getattr(sub, "sample_take", None)
        if take is None:
            return super()._take_subscription(sub)
        screen = getattr(sub, "screen", None)
        for _ in range(DRAIN if screen is not None else 1):
            try:
                with sub.handle:
                    got = take.take()
            except InvalidHandle:  # destroyed meanwhile
                return None
            if got is None:
                return None
            if screen is None:
                break
            if screen(*got):
                got[1]["screened"] = True
                break
        else:  # DRAIN samples dropped: the others' turn (the subscription is still ready)
            return None

        async def _execute():
            await await_or_execute(sub.callback, *got)

        return _execute
