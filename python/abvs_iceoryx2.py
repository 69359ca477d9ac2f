"""Depth maps, their confidence and point clouds of a running `abvs run`, received in Python over iceoryx2
shared memory.

The runtime publishes these iceoryx2 publish-subscribe services (runtime/src/bridges/iceoryx/), each
with a ``FrameHeader`` user header and an event service notified after every sample::

    {prefix}/depth       [f32]         row-major depth (m), width x height, NaN = invalid
    {prefix}/confidence  [f32]         row-major confidence of each depth pixel in [0, 1], width x height,
                                       0 = invalid; only with `abvs run --confidence`; the header is the
                                       depth sample's (match the two by ``header.seq``)
    {prefix}/cloud       [CloudPoint]  valid points only: x, y, z (m, left home camera frame), rgba

``prefix`` is ``abvs`` unless ``abvs run --service-prefix`` says otherwise. Needs the ``iceoryx2``
package of the runtime's iceoryx2 version (0.10) and numpy; ``scripts/setup.sh`` installs both into
``.deps/python``. Example::

    from abvs_iceoryx2 import Subscriber
    with Subscriber("depth") as sub:
        frame = sub.receive(timeout_s=1.0)      # None when nothing came in time
        if frame is not None:
            print(frame.header.seq, frame.data.shape)   # (480, 640) float32 at the default resolution, a view of shared memory
            frame.release()                     # give the sample back (at most 2 held at once)

``frame.data`` views the runtime's shared memory without a copy (read-only): copy it (``.copy()``)
to keep it after ``release()``. A subscriber may hold at most ``SERVICE["subscriber_max_borrowed"]``
samples; holding them longer only makes this subscriber miss frames, never the runtime wait.

The ctypes structures mirror the Rust ``#[repr(C)]`` types; iceoryx2 matches them by the names of
their ``#[type_name]`` attributes, size and alignment, and ``runtime/tests/python_layout.rs`` checks
every field's offset against the Rust layout.
"""
import ctypes
import time

import iceoryx2 as iox2
import numpy as np

__all__ = ["FrameHeader", "CloudPoint", "CLOUD_DTYPE", "SERVICE", "Frame", "Subscriber", "layout", "FLAG_MOTION_GATED"]

# FrameHeader.flags bit (Rust: abvs_runtime::bridges::iceoryx::FLAG_MOTION_GATED): the eyes moved too fast
# during the exposure, so the depth is all NaN and the cloud empty on purpose; a lost frame's seq is missing.
FLAG_MOTION_GATED = 1


class FrameHeader(ctypes.Structure):
    """The user header of both services (Rust: ``abvs_runtime::bridges::iceoryx::FrameHeader``)."""

    _fields_ = [
        ("seq", ctypes.c_uint64),  # pipeline frame sequence
        ("t_frame_ns", ctypes.c_int64),  # left mid-exposure, CLOCK_MONOTONIC ns
        ("t_publish_ns", ctypes.c_int64),  # when the sample was sent, CLOCK_MONOTONIC ns
        ("frame_id", ctypes.c_uint8 * 32),  # NUL-padded ASCII: "left_home_camera"
        ("pose_left", ctypes.c_double * 6),  # left camera vs its home: alpha, beta, gamma (deg), x, y, z (mm)
        ("pose_right", ctypes.c_double * 6),
        ("intrinsics", ctypes.c_double * 4),  # fx, fy, cx, cy of the rectified left image (px)
        ("width", ctypes.c_uint32),
        ("height", ctypes.c_uint32),
        ("baseline_m", ctypes.c_double),
        ("valid", ctypes.c_uint32),  # valid depth pixels / points
        ("flags", ctypes.c_uint32),  # FLAG_MOTION_GATED: depth NaN on purpose (eyes too fast)
    ]

    @staticmethod
    def type_name():
        return "abvs::FrameHeader/1"

    def frame_id_str(self):
        return bytes(self.frame_id).split(b"\0", 1)[0].decode("ascii", "replace")


class CloudPoint(ctypes.Structure):
    """One cloud point (Rust: ``abvs_runtime::bridges::iceoryx::CloudPoint``)."""

    _fields_ = [
        ("x", ctypes.c_float),
        ("y", ctypes.c_float),
        ("z", ctypes.c_float),
        ("rgba", ctypes.c_uint32),  # 0xAABBGGRR: bytes R, G, B, A in memory
    ]

    @staticmethod
    def type_name():
        return "abvs::CloudPoint/1"


# numpy's view of a CloudPoint (same bytes, field by field)
CLOUD_DTYPE = np.dtype({"names": ["x", "y", "z", "rgba"], "formats": ["<f4", "<f4", "<f4", "<u4"],
                        "offsets": [CloudPoint.x.offset, CloudPoint.y.offset, CloudPoint.z.offset,
                                    CloudPoint.rgba.offset], "itemsize": ctypes.sizeof(CloudPoint)})

# The services' settings: the runtime's BridgeConfig::default(); a service found with others is refused.
SERVICE = {
    "max_publishers": 1,
    "max_subscribers": 8,
    "subscriber_buffer": 2,
    "subscriber_max_borrowed": 2,
    "history": 1,
    "max_nodes": 20,
}

_PAYLOAD = {"depth": ctypes.c_float, "confidence": ctypes.c_float, "cloud": CloudPoint}


def layout():
    """{type name: {"size", "align", "fields": {name: offset}}} of the ctypes structures (the layout test)."""
    out = {}
    for t in (FrameHeader, CloudPoint):
        out[t.type_name()] = {
            "size": ctypes.sizeof(t),
            "align": ctypes.alignment(t),
            "fields": {name: getattr(t, name).offset for name, _ in t._fields_},
        }
    return out


class Frame:
    """One received sample: ``header`` (a FrameHeader in shared memory) and ``data`` (numpy, no copy):
    depth and confidence as float32 ``(height, width)``, a cloud as a ``(valid,)`` array of CLOUD_DTYPE.
    Valid until ``release()`` (or the end of a ``with`` block)."""

    def __init__(self, sample, topic):
        self._sample = sample
        self.header = sample.user_header().contents
        payload = sample.payload()
        h = self.header
        # the sample's own element count (the Slice's len() is the publisher's maximum)
        n = sample.header.number_of_elements
        if topic in ("depth", "confidence"):
            if n != h.width * h.height:
                raise ValueError(f"{topic} sample of {n} values for a {h.width}x{h.height} header")
            raw = (ctypes.c_float * n).from_address(payload.as_ptr())
            data = np.frombuffer(raw, dtype=np.float32).reshape(h.height, h.width)
        else:
            if h.valid > n:
                raise ValueError(f"cloud sample of {n} points for a header of {h.valid}")
            raw = (ctypes.c_uint8 * (n * ctypes.sizeof(CloudPoint))).from_address(payload.as_ptr())
            data = np.frombuffer(raw, dtype=CLOUD_DTYPE)[: h.valid]
        data.flags.writeable = False
        self.data = data

    def release(self):
        """Gives the sample back to the publisher (``data`` and ``header`` must not be used after)."""
        if self._sample is not None:
            self.data = None
            self.header = None
            self._sample.delete()
            self._sample = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.release()


class Subscriber:
    """Receives ``topic`` ("depth", "confidence" or "cloud") of the runtime publishing under ``prefix``."""

    def __init__(self, topic="depth", prefix="abvs"):
        if topic not in _PAYLOAD:
            raise ValueError(f"topic {topic!r}: expected 'depth', 'confidence' or 'cloud'")
        iox2.set_log_level_from_env_or(iox2.LogLevel.Error)
        self.topic = topic
        s = SERVICE
        self._node = iox2.NodeBuilder.new().create(iox2.ServiceType.Ipc)
        name = iox2.ServiceName.new(f"{prefix}/{topic}")
        # open_or_create: a subscriber may start before the runtime, with the runtime's settings
        self._service = (
            self._node.service_builder(name)
            .publish_subscribe(iox2.Slice[_PAYLOAD[topic]])
            .user_header(FrameHeader)
            .max_publishers(s["max_publishers"])
            .max_subscribers(s["max_subscribers"])
            .subscriber_max_buffer_size(s["subscriber_buffer"])
            .subscriber_max_borrowed_samples(s["subscriber_max_borrowed"])
            .history_size(s["history"])
            .enable_safe_overflow(True)
            .max_nodes(s["max_nodes"])
            .open_or_create()
        )
        self._subscriber = self._service.subscriber_builder().buffer_size(s["subscriber_buffer"]).create()
        event = (
            self._node.service_builder(iox2.ServiceName.new(f"{prefix}/{topic}/event"))
            .event()
            .max_notifiers(s["max_publishers"])
            .max_listeners(s["max_subscribers"])
            .max_nodes(s["max_nodes"])
            .open_or_create()
        )
        self._event = event
        self._listener = event.listener_builder().create()

    def receive(self, timeout_s=1.0):
        """The next sample as a Frame, asleep on the event service while none is there; None after
        ``timeout_s`` without one."""
        deadline = time.monotonic() + timeout_s
        while True:
            sample = self._subscriber.receive()
            if sample is not None:
                self._listener.try_wait()  # the notifications of what is taken now
                return Frame(sample, self.topic)
            left = deadline - time.monotonic()
            if left <= 0:
                return None
            # capped: a late joiner's history sample comes without a notification
            self._listener.timed_wait(iox2.Duration.from_secs_f64(min(left, 0.1)))

    def close(self):
        for attr in ("_listener", "_subscriber"):
            obj = getattr(self, attr, None)
            if obj is not None:
                obj.delete()
                setattr(self, attr, None)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
