"""Depth maps, their confidence and point clouds of a running `abvs run`, received in Python over iceoryx2
shared memory.

The runtime publishes these iceoryx2 publish-subscribe services (runtime/src/bridges/iceoryx/), each
with a ``FrameHeader`` user header and an event service notified after every sample::

    {prefix}/depth       [f32]         row-major depth (m), width x height, NaN = invalid
    {prefix}/confidence  [f32]         row-major confidence of each depth pixel in [0, 1], width x height,
                                       0 = invalid; only with `abvs run --confidence`; the header is the
                                       depth sample's (match the two by ``header.seq``)
    {prefix}/cloud       [CloudPoint]  valid points only: x, y, z (m, left home camera frame), rgba
    {prefix}/fovea/depth [f32]         the fovea (on by default, `abvs run --fovea off|WxH`): depth at the
                                       raw frames' native scale in a window around the fixation point; the
                                       header's intrinsics are the window's (native focal length, principal
                                       point placing it in the main map's rectified plane), flags bit 2 =
                                       the image centre at the default distance, not a measured fixation
    {prefix}/fovea/cloud [CloudPoint]  the fovea's valid points (left home camera frame)

and the gaze services (runtime/src/bridges/iceoryx/gaze.rs), through ``Gaze``::

    {prefix}/gaze/goal   GazeGoal      goals to the runtime (look_at, pursue, hold, home), any process
    {prefix}/gaze/state  GazeState     the gaze at every published frame, from the runtime

``prefix`` is ``abvs`` unless ``abvs run --service-prefix`` says otherwise. Needs the ``iceoryx2``
package of the runtime's iceoryx2 version (0.10) and numpy; ``scripts/setup.sh`` installs both into
``.deps/python``. Example::

    from abvs_iceoryx2 import Subscriber
    with Subscriber("depth") as sub:
        frame = sub.receive(timeout_s=1.0)      # None when nothing came in time
        if frame is not None:
            print(frame.header.seq, frame.data.shape)   # (480, 640) float32 at the default resolution, a view of shared memory
            frame.release()                     # give the sample back (at most 2 held at once)

Pointing the eyes::

    from abvs_iceoryx2 import Gaze
    with Gaze() as gaze:
        gaze.state(timeout_s=5.0)               # the runtime runs: states arrive (goals sent before are lost)
        goal = gaze.look_at(0.1, -0.05, 0.8)    # m, left home camera frame (x right, y down, z forward)
        s = gaze.state(timeout_s=1.0)           # the latest state, or None
        print(s.goal_id == goal, s.phase, s.reason, s.measured_fixation, s.vergence_m)

``frame.data`` views the runtime's shared memory without a copy (read-only): copy it (``.copy()``)
to keep it after ``release()``. A subscriber may hold at most ``SERVICE["subscriber_max_borrowed"]``
samples; holding them longer only makes this subscriber miss frames, never the runtime wait.

The ctypes structures mirror the Rust ``#[repr(C)]`` types; iceoryx2 matches them by the names of
their ``#[type_name]`` attributes, size and alignment, and ``runtime/tests/python_layout.rs`` checks
every field's offset against the Rust layout.
"""
import ctypes
import os
import time

import iceoryx2 as iox2
import numpy as np

__all__ = ["FrameHeader", "CloudPoint", "CLOUD_DTYPE", "SERVICE", "Frame", "Subscriber", "layout", "FLAG_MOTION_GATED",
           "GazeGoal", "GazeState", "GAZE_SERVICE", "PHASES", "REASONS", "State", "Gaze"]

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

_PAYLOAD = {
    "depth": ctypes.c_float,
    "confidence": ctypes.c_float,
    "cloud": CloudPoint,
    "fovea/depth": ctypes.c_float,
    "fovea/cloud": CloudPoint,
}


class GazeGoal(ctypes.Structure):
    """A gaze goal (Rust: ``abvs_runtime::bridges::iceoryx::gaze::GazeGoalWire``)."""

    _fields_ = [
        ("id", ctypes.c_uint64),  # chosen by the sender, non-zero; the states report it
        ("kind", ctypes.c_uint32),  # 1 look_at, 2 pursue, 3 hold, 4 home
        ("reserved", ctypes.c_uint32),
        ("point_m", ctypes.c_double * 3),  # m, left home camera frame
        ("velocity_m_s", ctypes.c_double * 3),  # m/s, pursue only
    ]

    @staticmethod
    def type_name():
        return "abvs::GazeGoal/1"


class GazeState(ctypes.Structure):
    """The gaze at one frame (Rust: ``abvs_runtime::bridges::iceoryx::gaze::GazeStateWire``)."""

    _fields_ = [
        ("seq", ctypes.c_uint64),  # the frame's pipeline seq (the depth sample's)
        ("t_frame_ns", ctypes.c_int64),  # left mid-exposure, CLOCK_MONOTONIC ns
        ("goal_id", ctypes.c_uint64),  # 0: no goal yet
        ("phase", ctypes.c_uint32),  # index in PHASES
        ("reason", ctypes.c_uint32),  # index in REASONS (0: none)
        ("commanded_m", ctypes.c_double * 3),  # NaN when none
        ("measured_m", ctypes.c_double * 3),  # closest approach of both optical axes; NaN if they do not meet
        ("vergence_m", ctypes.c_double),
        ("planned_ms", ctypes.c_double),
        ("flags", ctypes.c_uint32),  # 1: gated (saccade during the exposure), 2: gated (any reason)
        ("reserved", ctypes.c_uint32),
    ]

    @staticmethod
    def type_name():
        return "abvs::GazeState/1"


PHASES = ("idle", "saccade", "pursuit", "settled", "refused")
REASONS = (None, "non_finite", "behind_eyes", "too_near", "outside_workspace", "near_singular", "unreachable",
           "not_homed", "encoders_silent", "no_board", "send_failed")

# The gaze services' settings (Rust: gaze::goal_service, gaze::state_service).
GAZE_SERVICE = {
    "goal": {"max_publishers": 4, "max_subscribers": 8, "subscriber_buffer": 8, "subscriber_max_borrowed": 1,
             "history": 0},
    "state": {"max_publishers": 1, "max_subscribers": 8, "subscriber_buffer": 2, "subscriber_max_borrowed": 2,
              "history": 1},
}


class State:
    """One frame's gaze, copied out of shared memory: ``seq``, ``t_frame_ns``, ``goal_id``, ``phase`` (one of
    PHASES), ``reason`` (None or one of REASONS), ``commanded_fixation`` and ``measured_fixation`` ((x, y, z) m,
    left home camera frame, NaN when none), ``vergence_m``, ``planned_ms``, ``gated_saccade``, ``gated``."""

    def __init__(self, s):
        self.seq = s.seq
        self.t_frame_ns = s.t_frame_ns
        self.goal_id = s.goal_id
        self.phase = PHASES[s.phase] if s.phase < len(PHASES) else f"unknown({s.phase})"
        self.reason = REASONS[s.reason] if s.reason < len(REASONS) else f"unknown({s.reason})"
        self.commanded_fixation = tuple(s.commanded_m)
        self.measured_fixation = tuple(s.measured_m)
        self.vergence_m = s.vergence_m
        self.planned_ms = s.planned_ms
        self.gated_saccade = bool(s.flags & 1)
        self.gated = bool(s.flags & 2)

    def __repr__(self):
        return (f"State(seq={self.seq}, goal_id={self.goal_id}, phase={self.phase!r}, reason={self.reason!r}, "
                f"measured_fixation={self.measured_fixation}, vergence_m={self.vergence_m})")


class Gaze:
    """Points the eyes of the runtime publishing under ``prefix``: ``look_at``, ``pursue``, ``hold``, ``home``
    send a goal and return its id; ``state`` returns the latest frame's gaze. Goals sent before the runtime
    runs are lost: wait for a state first. The runtime takes the newest goal at its next frame."""

    def __init__(self, prefix="abvs"):
        iox2.set_log_level_from_env_or(iox2.LogLevel.Error)
        self._node = iox2.NodeBuilder.new().create(iox2.ServiceType.Ipc)

        def service(topic, t):
            s = GAZE_SERVICE[topic]
            return (
                self._node.service_builder(iox2.ServiceName.new(f"{prefix}/gaze/{topic}"))
                .publish_subscribe(t)
                .max_publishers(s["max_publishers"])
                .max_subscribers(s["max_subscribers"])
                .subscriber_max_buffer_size(s["subscriber_buffer"])
                .subscriber_max_borrowed_samples(s["subscriber_max_borrowed"])
                .history_size(s["history"])
                .enable_safe_overflow(True)
                .max_nodes(SERVICE["max_nodes"])
                .open_or_create()
            )

        self._goal_service = service("goal", GazeGoal)
        self._state_service = service("state", GazeState)
        self._publisher = self._goal_service.publisher_builder().create()
        self._subscriber = self._state_service.subscriber_builder().create()
        # ids unique across the processes that point the eyes
        self._next = (os.getpid() & 0xFFFFFFFF) << 24
        self._latest = None

    def _send(self, kind, point, velocity=(0.0, 0.0, 0.0)):
        self._next += 1
        g = GazeGoal(id=self._next, kind=kind)
        g.point_m[:] = [float(v) for v in point]
        g.velocity_m_s[:] = [float(v) for v in velocity]
        self._publisher.send_copy(g)
        return g.id

    def look_at(self, x, y, z):
        """Both eyes fixate (x, y, z) (m, left home camera frame); returns the goal's id."""
        return self._send(1, (x, y, z))

    def pursue(self, x, y, z, vx, vy, vz):
        """Both eyes follow a point at (x, y, z) now, moving at (vx, vy, vz) m/s; returns the goal's id."""
        return self._send(2, (x, y, z), (vx, vy, vz))

    def hold(self):
        """Stop where the eyes are; returns the goal's id."""
        return self._send(3, (0.0, 0.0, 0.0))

    def home(self):
        """Both eyes home; returns the goal's id."""
        return self._send(4, (0.0, 0.0, 0.0))

    def state(self, timeout_s=1.0):
        """The latest state received (waiting up to ``timeout_s`` for a first or newer one), or None."""
        deadline = time.monotonic() + timeout_s
        while True:
            newest = None
            while True:
                sample = self._subscriber.receive()
                if sample is None:
                    break
                newest = State(sample.payload().contents)
                sample.delete()
            if newest is not None:
                self._latest = newest
                return newest
            if time.monotonic() >= deadline:
                return None
            time.sleep(0.002)

    def close(self):
        for attr in ("_subscriber", "_publisher"):
            obj = getattr(self, attr, None)
            if obj is not None:
                obj.delete()
                setattr(self, attr, None)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def layout():
    """{type name: {"size", "align", "fields": {name: offset}}} of the ctypes structures (the layout test)."""
    out = {}
    for t in (FrameHeader, CloudPoint, GazeGoal, GazeState):
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
        if topic in ("depth", "confidence", "fovea/depth"):
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
    """Receives ``topic`` ("depth", "confidence", "cloud", "fovea/depth" or "fovea/cloud") of the runtime
    publishing under ``prefix``."""

    def __init__(self, topic="depth", prefix="abvs"):
        if topic not in _PAYLOAD:
            raise ValueError(f"topic {topic!r}: expected one of {', '.join(_PAYLOAD)}")
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
