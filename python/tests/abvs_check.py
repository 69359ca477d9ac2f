"""Checks of the runtime's outputs from Python, driven by the Rust tests (cli/tests/ros2_outputs.rs,
runtime/tests/python_layout.rs). Each subcommand prints one JSON object on its last line; the Rust
tests assert on it. Needs .deps/python (scripts/setup.sh): eclipse-zenoh, rosbags, mcap,
mcap-ros2-support, iceoryx2, numpy.

  layout                       the ctypes layout of FrameHeader and CloudPoint
  iox PREFIX [confidence]      receive depth and clouds (and the confidence) until stdin closes (prints
                               "ready" first)
  zenoh ENDPOINT PREFIX [PLAIN_ENDPOINT]
                               listen on ENDPOINT (Zenoh shared memory on) for the nine keys (the fovea's
                               three and the confidence included), and the iceoryx2 clouds, confidence and
                               fovea, until stdin closes; decode every message, compare clouds, the
                               confidence and the fovea's CameraInfo with iceoryx2 by stamp; count the large
                               payloads that came as shared memory; with PLAIN_ENDPOINT a second session
                               without shared memory listens there, and its payloads are compared with the
                               first's
  count ENDPOINT KEY...        listen on ENDPOINT for KEYs only, count the samples per key
  mcap FILE PREFIX             receive the iceoryx2 headers until stdin closes, then decode FILE
  rmw ENDPOINT                 listen on ENDPOINT as an rmw_zenoh (Jazzy) subscriber would: the nine typed
                               keys with the hashes rosbags computes, the liveliness tokens, the attachments
  gaze PREFIX X Y Z            wait for the runtime's gaze states, send look_at(X, Y Z), print the first
                               state that reports the goal (and the one before)
"""
import json
import os
import sys
import threading
import time

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))

import numpy as np  # noqa: E402

import abvs_iceoryx2 as abvs  # noqa: E402

KEYS = {
    "abvs/depth": "sensor_msgs/msg/Image",
    "abvs/camera_info": "sensor_msgs/msg/CameraInfo",
    "abvs/points": "sensor_msgs/msg/PointCloud2",
    "tf": "tf2_msgs/msg/TFMessage",
    "abvs/joint_states": "sensor_msgs/msg/JointState",
    "abvs/fovea/depth": "sensor_msgs/msg/Image",
    "abvs/fovea/camera_info": "sensor_msgs/msg/CameraInfo",
    "abvs/fovea/points": "sensor_msgs/msg/PointCloud2",
    "abvs/confidence": "sensor_msgs/msg/Image",
}


def stamp_ns(header):
    return header.stamp.sec * 1_000_000_000 + header.stamp.nanosec


def stdin_closed():
    """An event set when stdin reaches its end (the test's signal that the run is over)."""
    ev = threading.Event()

    def watch():
        sys.stdin.read()
        ev.set()

    threading.Thread(target=watch, daemon=True).start()
    return ev


class IoxCollector:
    """Receives the iceoryx2 topics on threads: depth shapes, headers, (optionally) clouds by stamp and the
    confidence (shape, range, header by seq)."""

    def __init__(self, prefix, keep_clouds, confidence=False, fovea=False):
        self.fovea = [abvs.Subscriber(t, prefix) for t in ("fovea/depth", "fovea/cloud")] if fovea else []
        self.fovea_frames = [0, 0]
        self.fovea_bad = []
        self.fovea_focal = set()
        self.fovea_headers = {}  # t_frame_ns -> (intrinsics, width, height, valid, flags)
        self.fovea_clouds = {}  # t_frame_ns -> cloud bytes (when keep_clouds)
        self.depth = abvs.Subscriber("depth", prefix)
        self.cloud = abvs.Subscriber("cloud", prefix)
        self.confidence = abvs.Subscriber("confidence", prefix) if confidence else None
        self.keep_clouds = keep_clouds
        self.depth_frames = 0
        self.cloud_frames = 0
        self.confidence_frames = 0
        self.bad_shapes = []
        self.bad_confidence = []
        self.headers = {}  # t_frame_ns -> (seq, intrinsics)
        self.clouds = {}  # t_frame_ns -> structured array copy
        self.confidence_headers = {}  # seq -> t_frame_ns, width, height, valid
        self.confidences = {}  # t_frame_ns -> confidence bytes (when keep_clouds)
        self.depth_by_seq = {}  # seq -> t_frame_ns, width, height, valid
        self.stop = threading.Event()
        self.threads = [threading.Thread(target=self.run_depth), threading.Thread(target=self.run_cloud)]
        if confidence:
            self.threads.append(threading.Thread(target=self.run_confidence))
        for k in range(len(self.fovea)):
            self.threads.append(threading.Thread(target=self.run_fovea, args=(k,)))
        for t in self.threads:
            t.start()

    def run_depth(self):
        while not self.stop.is_set():
            f = self.depth.receive(0.2)
            if f is None:
                continue
            with f:
                h = f.header
                if f.data.shape != (h.height, h.width) or f.data.dtype != np.float32:
                    self.bad_shapes.append([list(f.data.shape), h.height, h.width])
                self.headers[h.t_frame_ns] = (h.seq, list(h.intrinsics), h.frame_id_str())
                self.depth_frames += 1
                self.depth_by_seq[h.seq] = (h.t_frame_ns, h.width, h.height, h.valid)

    def run_confidence(self):
        while not self.stop.is_set():
            f = self.confidence.receive(0.2)
            if f is None:
                continue
            with f:
                h, c = f.header, f.data
                if c.shape != (h.height, h.width) or c.dtype != np.float32:
                    self.bad_confidence.append(["shape", list(c.shape), h.height, h.width])
                elif not (np.all(c >= 0.0) and np.all(c <= 1.0)):  # (NaN fails both)
                    self.bad_confidence.append(["range", h.seq, float(np.nanmin(c)), float(np.nanmax(c))])
                elif not np.any(c > 0.0) and not (h.flags & abvs.FLAG_MOTION_GATED):
                    # (a motion-gated frame has no valid pixel on purpose)
                    self.bad_confidence.append(["all zero", h.seq])
                self.confidence_headers[h.seq] = (h.t_frame_ns, h.width, h.height, h.valid)
                if self.keep_clouds:
                    self.confidences[h.t_frame_ns] = c.tobytes()
                self.confidence_frames += 1

    def run_fovea(self, k):
        while not self.stop.is_set():
            f = self.fovea[k].receive(0.2)
            if f is None:
                continue
            with f:
                h = f.header
                if k == 0:
                    if f.data.shape != (h.height, h.width) or f.data.dtype != np.float32:
                        self.fovea_bad.append(["shape", list(f.data.shape), h.height, h.width])
                    elif int(np.isfinite(f.data).sum()) != h.valid:
                        self.fovea_bad.append(["valid", h.seq, int(np.isfinite(f.data).sum()), h.valid])
                    self.fovea_focal.add(round(h.intrinsics[0], 3))
                    self.fovea_headers[h.t_frame_ns] = (list(h.intrinsics), h.width, h.height, h.valid, h.flags)
                elif len(f.data) != h.valid:
                    self.fovea_bad.append(["cloud", h.seq, len(f.data), h.valid])
                elif self.keep_clouds:
                    self.fovea_clouds[h.t_frame_ns] = f.data.tobytes()
                self.fovea_frames[k] += 1

    def run_cloud(self):
        while not self.stop.is_set():
            f = self.cloud.receive(0.2)
            if f is None:
                continue
            with f:
                if self.keep_clouds:
                    self.clouds[f.header.t_frame_ns] = (f.header.seq, f.data.copy())
                self.cloud_frames += 1

    def finish(self):
        self.stop.set()
        for t in self.threads:
            t.join()
        self.depth.close()
        self.cloud.close()
        if self.confidence is not None:
            self.confidence.close()
        for f in self.fovea:
            f.close()


def quat_matrix(q):
    x, y, z, w = q.x, q.y, q.z, q.w
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def tf_consistency(decoded, ns="abvs/"):
    """Frames whose depth, unprojected with their CameraInfo K and moved by /tf from the depth's frame_id to
    the cloud's, gives the cloud (`ns`: "abvs/" the main map's topics, "abvs/fovea/" the fovea's); returns
    (frames checked, largest point difference in m)."""
    by = lambda k: {stamp_ns(m.header): m for m in decoded[k]}  # noqa: E731
    depth, info, pts = by(ns + "depth"), by(ns + "camera_info"), by(ns + "points")
    tfs = {stamp_ns(m.transforms[0].header): m for m in decoded["tf"] if len(m.transforms)}
    checked, worst = 0, 0.0
    for t in sorted(set(depth) & set(info) & set(pts) & set(tfs)):
        dm, pm = depth[t], pts[t]
        d = np.frombuffer(dm.data.tobytes(), dtype="<f4").reshape(dm.height, dm.width)
        k = np.array(info[t].k).reshape(3, 3)
        v, u = np.nonzero(np.isfinite(d))  # row-major, as the cloud is built
        z = d[v, u].astype(np.float64)
        p = np.stack([(u - k[0, 2]) / k[0, 0] * z, (v - k[1, 2]) / k[1, 1] * z, z], 1)
        tr = [x for x in tfs[t].transforms if x.child_frame_id == dm.header.frame_id
              and x.header.frame_id == pm.header.frame_id]
        if len(tr) != 1:
            return checked, float("inf")
        r = quat_matrix(tr[0].transform.rotation)
        tv = tr[0].transform.translation
        q = p @ r.T + np.array([tv.x, tv.y, tv.z])
        c = np.frombuffer(pm.data.tobytes(), dtype=abvs.CLOUD_DTYPE)
        if len(c) != len(q):
            return checked, float("inf")
        cq = np.stack([c["x"], c["y"], c["z"]], 1).astype(np.float64)
        worst = max(worst, float(np.abs(q - cq).max()) if len(q) else 0.0)
        checked += 1
    return checked, worst


def cmd_layout():
    print(json.dumps(abvs.layout()))


def cmd_iox(prefix, *topics):
    done = stdin_closed()
    c = IoxCollector(prefix, keep_clouds=False, confidence="confidence" in topics, fovea="fovea" in topics)
    print("ready", flush=True)
    done.wait()
    time.sleep(0.5)  # samples still on their way
    c.finish()
    seqs = sorted(s for s, _, _ in c.headers.values())
    print(json.dumps({
        "depth_frames": c.depth_frames,
        "cloud_frames": c.cloud_frames,
        "bad_shapes": c.bad_shapes[:5],
        "first_seq": seqs[0] if seqs else None,
        "last_seq": seqs[-1] if seqs else None,
        "frame_ids": sorted({f for _, _, f in c.headers.values()}),
        "confidence_frames": c.confidence_frames,
        "bad_confidence": c.bad_confidence[:5],
        # confidence samples whose depth sample (same seq) came too, and of those, with the same header
        "confidence_with_depth": sum(s in c.depth_by_seq for s in c.confidence_headers),
        "confidence_same_header": sum(c.depth_by_seq.get(s) == v for s, v in c.confidence_headers.items()),
        "fovea_frames": c.fovea_frames,
        "fovea_bad": c.fovea_bad[:5],
        "fovea_focal": sorted(c.fovea_focal),
        "main_focal": sorted({round(i[0], 3) for _, i, _ in c.headers.values()}),
    }))


def zenoh_session(endpoint, shm=True):
    """A peer listening on ENDPOINT, without scouting, with Zenoh shared memory on or off."""
    import zenoh

    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("listen/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("transport/shared_memory/enabled", json.dumps(shm))
    return zenoh.open(conf)


# payloads this large go through the runtime's shared memory (bridges::zenoh::SHM_MIN_BYTES)
SHM_MIN_BYTES = 64 * 1024


def cmd_zenoh(endpoint, prefix, plain_endpoint=None):
    from rosbags.typesys import Stores, get_typestore

    done = stdin_closed()
    session = zenoh_session(endpoint)
    plain = zenoh_session(plain_endpoint, shm=False) if plain_endpoint else None
    raw = {k: [] for k in KEYS}
    plain_raw = {k: [] for k in KEYS}
    large, large_shm, plain_shm = {k: 0 for k in KEYS}, {k: 0 for k in KEYS}, [0]
    lock = threading.Lock()

    def on_sample(sample):
        # decoding waits for the end: the callback only keeps the bytes (a copy: the shared buffer goes back)
        k, b = str(sample.key_expr), sample.payload.to_bytes()
        with lock:
            raw[k].append(b)
            if len(b) >= SHM_MIN_BYTES:
                large[k] += 1
                large_shm[k] += sample.payload.as_shm() is not None

    def on_plain(sample):
        with lock:
            plain_raw[str(sample.key_expr)].append(sample.payload.to_bytes())
            plain_shm[0] += sample.payload.as_shm() is not None

    subs = [session.declare_subscriber(k, on_sample) for k in KEYS]
    if plain:
        subs += [plain.declare_subscriber(k, on_plain) for k in KEYS]
    iox = IoxCollector(prefix, keep_clouds=True, confidence=True, fovea=True)
    print("ready", flush=True)
    done.wait()
    time.sleep(1.0)
    iox.finish()
    for s in subs:
        s.undeclare()
    session.close()
    if plain:
        plain.close()

    ts = get_typestore(Stores.ROS2_HUMBLE)
    out = {"received": {k: len(v) for k, v in raw.items()}, "decode_errors": [], "iox_clouds": len(iox.clouds),
           "large": large, "large_shm": large_shm}
    if plain:
        # the session without shared memory: the same bytes (each of its payloads is one the first got)
        seen = {k: set(v) for k, v in raw.items()}
        out["plain"] = {"received": {k: len(v) for k, v in plain_raw.items()},
                        "equal": {k: sum(b in seen[k] for b in v) for k, v in plain_raw.items()},
                        "shm": plain_shm[0]}
    decoded = {k: [] for k in KEYS}
    for k, msgs in raw.items():
        for b in msgs:
            try:
                decoded[k].append(ts.deserialize_cdr(b, KEYS[k]))
            except Exception as e:  # noqa: BLE001 - every failure is reported to the test
                out["decode_errors"].append(f"{k}: {e}")
    out["decoded"] = {k: len(v) for k, v in decoded.items()}
    # clouds: the PointCloud2 of a frame against the iceoryx2 cloud of the same frame (same stamp)
    compared, equal, mismatches = 0, 0, []
    for m in decoded["abvs/points"]:
        t = stamp_ns(m.header)
        if t not in iox.clouds:
            continue
        seq, ref = iox.clouds[t]
        compared += 1
        names = [f.name for f in m.fields]
        pts = np.frombuffer(m.data.tobytes(), dtype=abvs.CLOUD_DTYPE)
        same = (names == ["x", "y", "z", "rgb"] and m.point_step == 16 and len(pts) == len(ref)
                and m.width * m.height == len(ref) and bytes(m.data.tobytes()) == ref.tobytes())
        equal += same
        if not same and len(mismatches) < 3:
            mismatches.append({"seq": seq, "points": len(pts), "iox_points": len(ref), "fields": names})
    out["clouds_compared"] = compared
    out["clouds_equal"] = equal
    out["cloud_mismatches"] = mismatches
    depth = decoded["abvs/depth"]
    out["depth_encoding"] = sorted({m.encoding for m in depth})
    out["depth_frame_ids"] = sorted({m.header.frame_id for m in depth})
    out["depth_shape_ok"] = all(len(m.data) == m.height * m.step and m.step == 4 * m.width for m in depth)
    tf_children = set()
    for m in decoded["tf"]:
        for tr in m.transforms:
            tf_children.add((tr.header.frame_id, tr.child_frame_id))
    out["tf"] = sorted(f"{a}->{b}" for a, b in tf_children)
    out["tf_checked"], out["tf_max_err_m"] = tf_consistency(decoded)
    out["joint_names"] = list(decoded["abvs/joint_states"][0].name) if decoded["abvs/joint_states"] else []
    out["fovea"] = fovea_checks(decoded, iox)
    out["confidence"] = confidence_checks(decoded, iox)
    print(json.dumps(out))


def confidence_checks(decoded, iox):
    """/abvs/confidence against the iceoryx2 confidence of the same frame (same stamp): the same float32
    bytes, the depth image's size and frame; a published depth pixel has a confidence above 0."""
    depth = {stamp_ns(m.header): m for m in decoded["abvs/depth"]}
    r = {"compared": 0, "equal": 0, "finite_depth_unconfident": 0, "bad": [],
         "encodings": sorted({m.encoding for m in decoded["abvs/confidence"]}),
         "frame_ids": sorted({m.header.frame_id for m in decoded["abvs/confidence"]})}
    for m in decoded["abvs/confidence"]:
        t = stamp_ns(m.header)
        if t not in iox.confidences or t not in depth:
            continue
        r["compared"] += 1
        dm = depth[t]
        c = np.frombuffer(m.data.tobytes(), dtype="<f4")
        d = np.frombuffer(dm.data.tobytes(), dtype="<f4")
        ok = (bytes(m.data.tobytes()) == iox.confidences[t] and (m.width, m.height, m.step) == (dm.width, dm.height, dm.step)
              and len(c) == len(d))
        r["equal"] += ok
        if ok:
            r["finite_depth_unconfident"] += int((np.isfinite(d) & ~(c > 0.0)).sum())
        elif len(r["bad"]) < 3:
            r["bad"].append({"size": [m.width, m.height, m.step], "depth": [dm.width, dm.height, dm.step]})
    return r


def cmd_count(endpoint, *keys):
    done = stdin_closed()
    session = zenoh_session(endpoint)
    n = {k: 0 for k in keys}
    lock = threading.Lock()

    def on_sample(sample):
        with lock:
            n[str(sample.key_expr)] += 1

    subs = [session.declare_subscriber(k, on_sample) for k in keys]
    print("ready", flush=True)
    done.wait()
    time.sleep(1.0)
    for s in subs:
        s.undeclare()
    session.close()
    print(json.dumps({"received": n}))


def fovea_checks(decoded, iox):
    """The fovea's topics against its iceoryx2 services, frame by frame (same stamp): CameraInfo K, P and
    size are the FrameHeader's intrinsics and window, the Image has that size and as many finite depths as
    the header counts valid, the PointCloud2 is the iceoryx2 cloud's bytes; a motion-gated frame (flag in the
    header) has no valid depth and no point; the depth unprojected with the CameraInfo and moved by /tf is the
    cloud."""
    by = lambda k: {stamp_ns(m.header): m for m in decoded[k]}  # noqa: E731
    depth, info, pts = by("abvs/fovea/depth"), by("abvs/fovea/camera_info"), by("abvs/fovea/points")
    r = {"compared": 0, "info_equal": 0, "depth_equal": 0, "cloud_equal": 0, "gated": 0, "bad": [],
         "frame_ids": sorted({m.header.frame_id for m in depth.values()} | {m.header.frame_id for m in info.values()}),
         "cloud_frame_ids": sorted({m.header.frame_id for m in pts.values()}),
         "focal_above_main": all(info[t].k[0] > 2.0 * m.k[0] for m in decoded["abvs/camera_info"]
                                 for t in [stamp_ns(m.header)] if t in info)}
    for t in sorted(set(depth) & set(info) & set(pts) & set(iox.fovea_headers) & set(iox.fovea_clouds)):
        (fx, fy, cx, cy), w, h, valid, flags = iox.fovea_headers[t]
        ci, dm, pm = info[t], depth[t], pts[t]
        r["compared"] += 1
        ok_info = (list(ci.k) == [fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0]
                   and list(ci.p) == [fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0]
                   and (ci.width, ci.height) == (w, h) and list(ci.d) == [0.0] * 5)
        d = np.frombuffer(dm.data.tobytes(), dtype="<f4")
        finite = int(np.isfinite(d).sum())
        ok_depth = (dm.width, dm.height, dm.step, len(d)) == (w, h, 4 * w, w * h) and finite == valid
        ok_cloud = bytes(pm.data.tobytes()) == iox.fovea_clouds[t] and pm.width == valid
        if flags & abvs.FLAG_MOTION_GATED:
            r["gated"] += 1
            ok_depth = ok_depth and finite == 0 and pm.width == 0
        r["info_equal"] += ok_info
        r["depth_equal"] += ok_depth
        r["cloud_equal"] += ok_cloud
        if not (ok_info and ok_depth and ok_cloud) and len(r["bad"]) < 3:
            r["bad"].append({"k": list(ci.k), "size": [ci.width, ci.height], "header": [fx, fy, cx, cy, w, h, valid],
                             "finite": finite, "points": pm.width})
    r["tf_checked"], r["tf_max_err_m"] = tf_consistency(decoded, "abvs/fovea/")
    return r


def cmd_mcap(path, prefix):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    done = stdin_closed()
    iox = IoxCollector(prefix, keep_clouds=False, fovea=True)
    print("ready", flush=True)
    done.wait()
    time.sleep(0.5)
    iox.finish()
    counts, schemas, errors = {}, {}, []
    last_stamp, back = {}, 0
    k_checked, k_equal, k_mismatch = 0, 0, []
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        it = reader.iter_decoded_messages()
        while True:
            try:
                schema, channel, message, msg = next(it)
            except StopIteration:
                break
            except Exception as e:  # noqa: BLE001 - a message that does not decode is reported
                errors.append(str(e))
                break
            topic = channel.topic
            counts[topic] = counts.get(topic, 0) + 1
            schemas[topic] = [schema.name, schema.encoding, channel.message_encoding]
            heads = [tr.header for tr in msg.transforms] if topic == "/tf" else [msg.header]
            for h in heads:
                t = stamp_ns(h)
                if t < last_stamp.get(topic, -1):
                    back += 1
                last_stamp[topic] = t
            if topic in ("/abvs/camera_info", "/abvs/fovea/camera_info"):
                t = stamp_ns(msg.header)
                heads = iox.headers if topic == "/abvs/camera_info" else iox.fovea_headers
                if t in heads:
                    k_checked += 1
                    fx, fy, cx, cy = heads[t][0 if topic != "/abvs/camera_info" else 1]
                    k = list(msg.k)
                    if k == [fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0]:
                        k_equal += 1
                    elif len(k_mismatch) < 3:
                        k_mismatch.append({"k": k, "intrinsics": [fx, fy, cx, cy]})
        summary = reader.get_summary()
        profile = reader.get_header().profile
    print(json.dumps({
        "messages": counts,
        "schemas": schemas,
        "decode_errors": errors,
        "stamps_back": back,
        "profile": profile,
        "k_checked": k_checked,
        "k_equal": k_equal,
        "k_mismatch": k_mismatch,
        "iox_headers": len(iox.headers),
        "summary_messages": summary.statistics.message_count if summary and summary.statistics else None,
    }))


TOPICS = {
    "/abvs/depth": "sensor_msgs/msg/Image",
    "/abvs/camera_info": "sensor_msgs/msg/CameraInfo",
    "/abvs/points": "sensor_msgs/msg/PointCloud2",
    "/tf": "tf2_msgs/msg/TFMessage",
    "/abvs/joint_states": "sensor_msgs/msg/JointState",
    "/abvs/fovea/depth": "sensor_msgs/msg/Image",
    "/abvs/fovea/camera_info": "sensor_msgs/msg/CameraInfo",
    "/abvs/fovea/points": "sensor_msgs/msg/PointCloud2",
    "/abvs/confidence": "sensor_msgs/msg/Image",
}


def cmd_rmw(endpoint):
    """What a ROS 2 Jazzy node on rmw_zenoh needs of a publisher, checked without ROS 2: keys
    <domain>/<topic>/<pkg>::msg::dds_::<Type>_/<RIHS01 hash> (hashes from rosbags' Jazzy type store), a
    liveliness token per publisher and for the node, a 33-byte attachment on every sample."""
    import hashlib
    import struct

    import zenoh
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_JAZZY)
    done = stdin_closed()
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("listen/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    session = zenoh.open(conf)
    keys = {}
    for topic, ty in TOPICS.items():
        pkg, _, name = ty.split("/")
        keys[f"0/{topic[1:]}/{pkg}::msg::dds_::{name}_/{ts.hash_rihs01(ty)}"] = topic
    raw = {t: [] for t in TOPICS}
    tokens, gone, peers = [], [], set()
    lock = threading.Lock()

    def on_sample(sample):
        a = sample.attachment.to_bytes() if sample.attachment is not None else b""
        with lock:
            raw[keys[str(sample.key_expr)]].append((sample.payload.to_bytes(), a, time.time_ns()))

    def on_token(sample):
        with lock:
            (tokens if sample.kind == zenoh.SampleKind.PUT else gone).append(str(sample.key_expr))

    subs = [session.declare_subscriber(k, on_sample) for k in keys]
    lv = session.liveliness().declare_subscriber("@ros2_lv/0/**", on_token, history=True)
    print("ready", flush=True)
    while not done.wait(0.1):
        peers.update(str(z) for z in session.info.peers_zid())
    time.sleep(1.0)
    for s in subs:
        s.undeclare()
    lv.undeclare()
    session.close()

    out = {"received": {}, "decoded": {}, "decode_errors": [], "attachment_errors": [], "seq_first": {},
           "seq_steps_ok": {}, "gids": {}, "tokens": sorted(set(tokens)), "tokens_gone": sorted(set(gone)),
           "peers": sorted(peers), "token_errors": []}
    for topic, samples in raw.items():
        out["received"][topic] = len(samples)
        seqs, gids, n = [], set(), 0
        for payload, a, t_rx in samples:
            try:
                ts.deserialize_cdr(payload, TOPICS[topic])
                n += 1
            except Exception as e:  # noqa: BLE001 - every failure is reported to the test
                out["decode_errors"].append(f"{topic}: {e}")
            if len(a) != 33 or a[16] != 0x10:
                out["attachment_errors"].append(f"{topic}: {len(a)} bytes {a[:17].hex()}")
                continue
            seq, t_src = struct.unpack_from("<qq", a)
            seqs.append(seq)
            gids.add(a[17:].hex())
            # the source time is the wall clock at sending: before the arrival, not long before
            if not 0 <= t_rx - t_src < 30_000_000_000:
                out["attachment_errors"].append(f"{topic}: source time {t_src} vs received {t_rx}")
        out["decoded"][topic] = n
        out["seq_first"][topic] = seqs[0] if seqs else None
        out["seq_steps_ok"][topic] = all(b - a == 1 for a, b in zip(seqs, seqs[1:]))
        out["gids"][topic] = sorted(gids)
    # every publisher's token: @ros2_lv/0/<zid>/<node id>/<id>/MP/%/%/abvs/<topic>/<type>/<hash>/<qos>, its
    # zid a peer's, and its GID the first 16 bytes of the token's SHA-256 (the runtime's rule)
    out["publishers"] = {}
    for tok in out["tokens"]:
        p = tok.split("/")
        if len(p) == 9 and p[5] == "NN":
            out["node"] = {"zid_is_peer": p[2] in peers, "ids": p[3:5], "enclave_ns_name": p[6:9]}
            continue
        if len(p) != 13 or p[5] != "MP":
            out["token_errors"].append(tok)
            continue
        topic = p[9].replace("%", "/")
        ty = TOPICS.get(topic, "")
        pkg, _, name = ty.partition("/msg/")
        gid = hashlib.sha256(tok.encode()).digest()[:16].hex()
        out["publishers"][topic] = {
            "zid_is_peer": p[2] in peers,
            "node": p[6:9],
            "type_ok": p[10] == f"{pkg}::msg::dds_::{name}_" and p[11] == ts.hash_rihs01(ty),
            "qos": p[12],
            "gid_matches_samples": out["gids"].get(topic) == [gid],
            "ids": p[3:5],
        }
    print(json.dumps(out))


def cmd_gaze(prefix, x, y, z):
    with abvs.Gaze(prefix) as gaze:
        before = gaze.state(timeout_s=60.0)
        if before is None:
            print(json.dumps({"error": "no gaze state in 60 s"}))
            return
        goal = gaze.look_at(float(x), float(y), float(z))
        deadline = time.monotonic() + 30.0
        s = None
        while time.monotonic() < deadline:
            s = gaze.state(timeout_s=1.0)
            if s is not None and s.goal_id == goal:
                break
        got = s if s is not None and s.goal_id == goal else None

        def d(st):
            return None if st is None else {
                "seq": st.seq, "goal_id": st.goal_id, "phase": st.phase, "reason": st.reason,
                "commanded_fixation": [None if v != v else v for v in st.commanded_fixation],
                "measured_fixation": [None if v != v else v for v in st.measured_fixation],
                "vergence_m": None if st.vergence_m != st.vergence_m else st.vergence_m,
            }
        print(json.dumps({"goal": goal, "before": d(before), "state": d(got)}))


def main(argv):
    if not argv:
        sys.exit(__doc__)
    cmd, args = argv[0], argv[1:]
    {"layout": cmd_layout, "iox": cmd_iox, "zenoh": cmd_zenoh, "count": cmd_count, "mcap": cmd_mcap, "rmw": cmd_rmw,
     "gaze": cmd_gaze}[cmd](*args)


if __name__ == "__main__":
    main(sys.argv[1:])
