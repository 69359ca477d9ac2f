//! V4L2 capture of the two eye cameras: [`V4lCamera`] (one device, MMAP streaming) and
//! [`StereoCapture`] (a thread per camera feeding a [`Pairer`]).
//!
//! Everything that does not need a device (flag interpretation, timestamp conversion, format and
//! stride validation, sequence accounting, the capture threads and pairing) is a pure function or
//! generic over [`FrameSource`], so it is tested without cameras; only the ioctls themselves are not.
//!
//! Timestamps: a frame's `t_start_ns` is the start of exposure of its first row, on
//! CLOCK_MONOTONIC (the clock the encoder link maps the drive board onto). Buffers stamped with
//! another clock are refused. Drivers stamp either the start of exposure (`TSTAMP_SRC_SOE`) or the
//! end of the frame (`TSTAMP_SRC_EOF`, when the last pixel arrived); for the OV8856's rolling shutter
//! the last row ends exposing `exposure + readout` after the first row started, so an EOF stamp is
//! moved back by exactly that ([`start_of_exposure_ns`]). With [`RowReference::CentreRow`] the
//! reference is the middle row instead (half a readout later), which is the better single instant
//! for a whole rolling-shutter frame.
use std::io;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc::{self, Receiver, SyncSender, TryRecvError};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;

use v4l::buffer::Type as BufType;
use v4l::io::mmap::Stream as MmapStream;
use v4l::io::traits::CaptureStream;
use v4l::video::Capture;
use v4l::{Device, FourCC};

use super::pairing::{PairStats, Pairer, PairerConfig, Side};
use super::pixel::{fourcc_string, GrayConverter, PixelError, PixelFormat};
use abvs_runtime_core::messages::{Frame, FramePair};

/// `V4L2_BUF_FLAG_ERROR`: the buffer was filled but its data is corrupted.
pub const BUF_FLAG_ERROR: u32 = 0x0000_0040;
/// `V4L2_BUF_FLAG_TIMESTAMP_MASK` and its values.
pub const BUF_FLAG_TIMESTAMP_MASK: u32 = 0x0000_e000;
/// The driver does not say which clock stamped the buffer.
pub const BUF_FLAG_TIMESTAMP_UNKNOWN: u32 = 0x0000_0000;
/// Stamped on CLOCK_MONOTONIC (what the runtime needs).
pub const BUF_FLAG_TIMESTAMP_MONOTONIC: u32 = 0x0000_2000;
/// The timestamp was copied from an output buffer (not a capture time).
pub const BUF_FLAG_TIMESTAMP_COPY: u32 = 0x0000_4000;
/// `V4L2_BUF_FLAG_TSTAMP_SRC_MASK` and its values.
pub const BUF_FLAG_TSTAMP_SRC_MASK: u32 = 0x0007_0000;
/// Stamped at the end of the frame (its last pixel received).
pub const BUF_FLAG_TSTAMP_SRC_EOF: u32 = 0x0000_0000;
/// Stamped at the start of exposure.
pub const BUF_FLAG_TSTAMP_SRC_SOE: u32 = 0x0001_0000;
/// `V4L2_CID_EXPOSURE_ABSOLUTE` (units of 100 us), read when no exposure is configured.
pub const CID_EXPOSURE_ABSOLUTE: u32 = 0x009a_0902;

/// What a buffer's timestamp marks.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TimestampSource {
    /// Start of exposure of the first row.
    StartOfExposure,
    /// When the last pixel of the frame was received.
    EndOfFrame,
}

/// Which row's exposure start `Frame::t_start_ns` refers to.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum RowReference {
    /// The first row (V4L2's meaning of start of exposure).
    #[default]
    FirstRow,
    /// The middle row: half the readout time after the first.
    CentreRow,
}

/// What to ask of one camera.
#[derive(Clone, Debug, PartialEq)]
pub struct CaptureConfig {
    /// Frame width (px).
    pub width: u32,
    /// Frame height (px).
    pub height: u32,
    /// Requested V4L2 FourCC; the driver may substitute another supported one.
    pub fourcc: [u8; 4],
    /// Frame rate (Hz).
    pub fps: u32,
    /// MMAP buffers queued in the driver (more buffers absorb scheduling hiccups, add no latency).
    pub buffers: u32,
    /// Raw Bayer black level in 10-bit units (the OV8856 pedestal is 64); 0 gives a plain `>> 2`.
    pub black_level: u16,
    /// Exposure time, ns; `None` reads `V4L2_CID_EXPOSURE_ABSOLUTE` once at open. Exposure must
    /// be manual (fixed): it is not re-read per frame.
    pub exposure_ns: Option<i64>,
    /// Time from the first row's to the last row's readout, ns (rolling shutter); needed to move
    /// end-of-frame timestamps back to the start of exposure.
    pub readout_ns: i64,
    /// Which row's exposure start the frames' `t_start_ns` gives.
    pub reference: RowReference,
    /// How long one dequeue waits before the capture thread re-checks for shutdown.
    pub poll_timeout: Duration,
}

impl Default for CaptureConfig {
    /// The eye cameras: 1600x1200 RAW10 (MIPI packed, GRBG) at 25 fps. Check the order with
    /// `v4l2-ctl -d /dev/videoN --list-formats-ext`; readout of 1200 rows is about 30 ms at 25 fps.
    fn default() -> Self {
        CaptureConfig {
            width: 1600,
            height: 1200,
            fourcc: *b"pgAA",
            fps: 25,
            buffers: 4,
            black_level: 64,
            exposure_ns: None,
            readout_ns: 30_000_000,
            reference: RowReference::FirstRow,
            poll_timeout: Duration::from_millis(200),
        }
    }
}

/// What the driver agreed to (`VIDIOC_S_FMT`'s answer).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct NegotiatedFormat {
    /// Frame width (px).
    pub width: u32,
    /// Frame height (px).
    pub height: u32,
    /// The pixel format (V4L2 FourCC).
    pub fourcc: [u8; 4],
    /// Bytes per row, padding included.
    pub bytesperline: u32,
    /// Bytes per frame buffer.
    pub sizeimage: u32,
}

/// Capture failures; each names the device.
#[derive(Debug, thiserror::Error)]
pub enum CaptureError {
    #[error("{path}: no such video device (list the cameras with `v4l2-ctl --list-devices`)")]
    /// No device at the path.
    DeviceMissing {
        /// The device node.
        path: PathBuf,
    },
    #[error("{path}: cannot open: {source}")]
    /// The device exists but does not open (permissions, busy).
    Open {
        /// The device node.
        path: PathBuf,
        /// What the system said.
        source: io::Error,
    },
    #[error("{path}: not a V4L2 video capture device ({reason}; list the cameras with `v4l2-ctl --list-devices`)")]
    /// The node is not a V4L2 video capture device.
    NotVideoCapture {
        /// The device node.
        path: PathBuf,
        /// What it is, or why it does not answer as one.
        reason: String,
    },
    #[error("{path}: {source}")]
    /// A pixel format the runtime cannot convert.
    Format {
        /// The device node.
        path: PathBuf,
        /// Why.
        source: PixelError,
    },
    #[error("{path}: asked for {requested}, the driver set {got}")]
    /// The driver set another size or pixel format than asked for.
    FormatChanged {
        /// The device node.
        path: PathBuf,
        /// What was asked for.
        requested: String,
        /// What the driver set.
        got: String,
    },
    #[error("{path}: asked for {requested} fps, the driver set a frame interval of {num}/{den} s")]
    /// The driver set another frame rate than asked for.
    FrameRate {
        /// The device node.
        path: PathBuf,
        /// The frame rate asked for (Hz).
        requested: u32,
        /// Numerator of the frame interval set (s).
        num: u32,
        /// Denominator of the frame interval set.
        den: u32,
    },
    #[error("{path}: buffer timestamps are {clock}, not CLOCK_MONOTONIC (flags {flags:#010x}); they cannot be aligned with the encoders")]
    /// Buffer timestamps on another clock than CLOCK_MONOTONIC: they cannot be aligned with the encoders.
    NotMonotonic {
        /// The device node.
        path: PathBuf,
        /// The clock the flags name.
        clock: &'static str,
        /// The buffer's flags.
        flags: u32,
    },
    #[error("{path}: no exposure time: set CaptureConfig::exposure_ns (EXPOSURE_ABSOLUTE unreadable: {reason})")]
    /// No exposure time configured, and the camera's unreadable.
    NoExposure {
        /// The device node.
        path: PathBuf,
        /// Why the camera's could not be read.
        reason: String,
    },
    #[error("{path}: frame {seq} is corrupted (V4L2_BUF_FLAG_ERROR)")]
    /// The driver flagged a frame as corrupted.
    Corrupt {
        /// The device node.
        path: PathBuf,
        /// The frame's sequence number from the driver.
        seq: u32,
    },
    #[error("{path}: frame {seq}: {source}")]
    /// A frame that does not convert to gray (a short buffer).
    Convert {
        /// The device node.
        path: PathBuf,
        /// The frame's sequence number from the driver.
        seq: u32,
        /// Why.
        source: PixelError,
    },
    #[error("{path}: {op}: {source}")]
    /// A V4L2 call failed.
    Io {
        /// The device node.
        path: PathBuf,
        /// The call.
        op: &'static str,
        /// What the system said.
        source: io::Error,
    },
    #[error("{path}: no frame within the poll timeout")]
    /// No frame within the poll timeout.
    Timeout {
        /// The device node.
        path: PathBuf,
    },
    /// Both capture threads have stopped.
    #[error("both capture threads have stopped")]
    Stopped,
}

impl CaptureError {
    /// Whether the stream can go on after this error (one bad frame, or a poll timeout).
    pub fn is_transient(&self) -> bool {
        matches!(self, CaptureError::Corrupt { .. } | CaptureError::Convert { .. } | CaptureError::Timeout { .. })
    }
}

impl From<CaptureError> for abvs_runtime_core::error::RuntimeError {
    fn from(e: CaptureError) -> Self {
        abvs_runtime_core::error::RuntimeError::Capture(Box::new(e))
    }
}

/// The timestamp source of a buffer, or why its clock is unusable.
pub fn timestamp_source(flags: u32) -> Result<TimestampSource, &'static str> {
    match flags & BUF_FLAG_TIMESTAMP_MASK {
        BUF_FLAG_TIMESTAMP_MONOTONIC => {}
        BUF_FLAG_TIMESTAMP_UNKNOWN => return Err("of unknown clock"),
        BUF_FLAG_TIMESTAMP_COPY => return Err("copied from the application"),
        _ => return Err("of an unrecognised clock type"),
    }
    Ok(if flags & BUF_FLAG_TSTAMP_SRC_MASK == BUF_FLAG_TSTAMP_SRC_SOE {
        TimestampSource::StartOfExposure
    } else {
        TimestampSource::EndOfFrame
    })
}

/// A `struct timeval` as nanoseconds (saturating: a garbage stamp must not wrap into a plausible one).
pub fn timeval_to_ns(sec: i64, usec: i64) -> i64 {
    sec.saturating_mul(1_000_000_000).saturating_add(usec.saturating_mul(1_000))
}

/// Start of exposure (of the [`RowReference`] row) from a buffer timestamp; see the module doc.
pub fn start_of_exposure_ns(
    stamp_ns: i64,
    source: TimestampSource,
    exposure_ns: i64,
    readout_ns: i64,
    reference: RowReference,
) -> i64 {
    let first_row = match source {
        TimestampSource::StartOfExposure => stamp_ns,
        TimestampSource::EndOfFrame => stamp_ns.saturating_sub(exposure_ns).saturating_sub(readout_ns),
    };
    match reference {
        RowReference::FirstRow => first_row,
        RowReference::CentreRow => first_row.saturating_add(readout_ns / 2),
    }
}

/// The row (fraction of the image) whose start of exposure the stamps fix independently of the readout
/// ([`abvs_runtime_core::messages::SourcePair::readout_anchor`]): the first row for start-of-exposure stamps, the last
/// for end-of-frame ones (the readout is subtracted to reach the first row).
pub fn readout_anchor(source: TimestampSource, reference: RowReference) -> f64 {
    match (source, reference) {
        (TimestampSource::StartOfExposure, RowReference::FirstRow) => 0.0,
        (TimestampSource::StartOfExposure, RowReference::CentreRow) => -0.5,
        (TimestampSource::EndOfFrame, RowReference::FirstRow) => 1.0,
        (TimestampSource::EndOfFrame, RowReference::CentreRow) => 0.5,
    }
}

/// Checks the driver's answer to the format request and returns the layout to convert from.
/// A different size is refused (calibration is per resolution); another supported FourCC is used.
pub fn validate_format(requested: &CaptureConfig, got: &NegotiatedFormat) -> Result<PixelFormat, String> {
    let describe = |w: u32, h: u32, f: [u8; 4]| format!("{w}x{h} {}", fourcc_string(f));
    let req = describe(requested.width, requested.height, requested.fourcc);
    let have = describe(got.width, got.height, got.fourcc);
    if (got.width, got.height) != (requested.width, requested.height) {
        return Err(format!("asked for {req}, the driver set {have}"));
    }
    let format =
        PixelFormat::from_fourcc(got.fourcc).map_err(|e| format!("asked for {req}, the driver set {have}: {e}"))?;
    let stride = got.bytesperline as usize;
    format.validate(got.width, got.height, stride).map_err(|e| e.to_string())?;
    let need = format.min_buffer_len(got.width, got.height, stride);
    if (got.sizeimage as usize) < need {
        return Err(format!("{have}: sizeimage {} is below the {need} bytes the layout needs", got.sizeimage));
    }
    Ok(format)
}

/// Checks the frame interval the driver set against the requested rate (within 1%).
pub fn frame_interval_ok(fps: u32, num: u32, den: u32) -> bool {
    if num == 0 || den == 0 || fps == 0 {
        return false;
    }
    let got = f64::from(den) / f64::from(num);
    (got - f64::from(fps)).abs() <= 0.01 * f64::from(fps)
}

/// One step of a stream's 32-bit V4L2 sequence counter.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SeqStep {
    /// The first frame of the stream.
    First,
    /// The expected next frame.
    Next,
    /// `n` frames were skipped (dropped by the driver).
    Gap(u64),
    /// Not after the previous one (a reset or a repeated buffer).
    Backwards,
}

/// Widens the V4L2 `u32` sequence to `u64` across wrap-arounds and classifies each step.
#[derive(Clone, Copy, Debug, Default)]
pub struct SeqCounter {
    last: Option<(u32, u64)>,
}

impl SeqCounter {
    /// The widened sequence number of `seq` and what the step was. Steps of 2^31 or more are taken
    /// as going backwards; a backwards frame keeps the previous number, so the pairer discards it.
    pub fn step(&mut self, seq: u32) -> (u64, SeqStep) {
        let Some((prev, wide)) = self.last else {
            self.last = Some((seq, u64::from(seq)));
            return (u64::from(seq), SeqStep::First);
        };
        let d = seq.wrapping_sub(prev);
        if d == 0 || d >= 1 << 31 {
            return (wide, SeqStep::Backwards);
        }
        let now = wide + u64::from(d);
        self.last = Some((seq, now));
        (now, if d == 1 { SeqStep::Next } else { SeqStep::Gap(u64::from(d - 1)) })
    }
}

/// The V4L2 error for a failed open: a missing node gets the `v4l2-ctl` hint.
pub fn open_error(path: &Path, e: io::Error) -> CaptureError {
    if e.kind() == io::ErrorKind::NotFound {
        CaptureError::DeviceMissing { path: path.to_path_buf() }
    } else {
        CaptureError::Open { path: path.to_path_buf(), source: e }
    }
}

/// A source of gray frames: a camera, or a stand-in in tests.
pub trait FrameSource: Send {
    /// The next frame, written into `gray` (a recycled buffer, resized as needed).
    fn next_frame(&mut self, gray: Vec<u8>) -> Result<Frame, CaptureError>;
    /// Bytes of one gray frame (to size recycled buffers).
    fn frame_len(&self) -> usize;
}

/// One V4L2 camera streaming MMAP buffers, converted to gray.
pub struct V4lCamera {
    path: PathBuf,
    // Declared before `device`: the stream's buffers are unmapped before the device closes.
    stream: MmapStream<'static>,
    _device: Device,
    converter: GrayConverter,
    format: NegotiatedFormat,
    cfg: CaptureConfig,
    exposure_ns: i64,
    seq: SeqCounter,
    timestamp_source: Option<TimestampSource>,
}

impl V4lCamera {
    /// Opens `path`, negotiates format and frame rate, and maps `cfg.buffers` buffers.
    pub fn open(path: impl AsRef<Path>, cfg: CaptureConfig) -> Result<Self, CaptureError> {
        let path = path.as_ref().to_path_buf();
        if !path.exists() {
            return Err(CaptureError::DeviceMissing { path });
        }
        let device = Device::with_path(&path).map_err(|e| open_error(&path, e))?;
        let not_capture = |reason: String| CaptureError::NotVideoCapture { path: path.clone(), reason };
        let caps = device.query_caps().map_err(|e| not_capture(format!("VIDIOC_QUERYCAP: {e}")))?;
        use v4l::capability::Flags;
        if !caps.capabilities.contains(Flags::VIDEO_CAPTURE) {
            return Err(not_capture(format!("{} ({}) has no single-planar capture", caps.card, caps.driver)));
        }
        if !caps.capabilities.contains(Flags::STREAMING) {
            return Err(not_capture(format!("{} ({}) cannot stream", caps.card, caps.driver)));
        }

        let io_err = |op| {
            let path = path.clone();
            move |source| CaptureError::Io { path, op, source }
        };
        let want = v4l::Format::new(cfg.width, cfg.height, FourCC::new(&cfg.fourcc));
        let got = device.set_format(&want).map_err(io_err("VIDIOC_S_FMT"))?;
        let format = NegotiatedFormat {
            width: got.width,
            height: got.height,
            fourcc: got.fourcc.repr,
            bytesperline: got.stride,
            sizeimage: got.size,
        };
        let pixel = validate_format(&cfg, &format).map_err(|reason| CaptureError::FormatChanged {
            path: path.clone(),
            requested: format!("{}x{} {}", cfg.width, cfg.height, fourcc_string(cfg.fourcc)),
            got: reason,
        })?;
        let converter =
            GrayConverter::new(pixel, format.width, format.height, format.bytesperline as usize, cfg.black_level)
                .map_err(|source| CaptureError::Format { path: path.clone(), source })?;

        // Sensor-subdevice pipelines set the rate through VBLANK and answer S_PARM with ENOTTY:
        // that is not an error, a different rate accepted by the driver is.
        if let Ok(p) = device.set_params(&v4l::video::capture::Parameters::with_fps(cfg.fps)) {
            let (num, den) = (p.interval.numerator, p.interval.denominator);
            if !frame_interval_ok(cfg.fps, num, den) {
                return Err(CaptureError::FrameRate { path, requested: cfg.fps, num, den });
            }
        }

        let exposure_ns = match cfg.exposure_ns {
            Some(e) => e,
            None => match device.control(CID_EXPOSURE_ABSOLUTE) {
                Ok(v4l::control::Control { value: v4l::control::Value::Integer(v), .. }) => v * 100_000,
                Ok(c) => return Err(CaptureError::NoExposure { path, reason: format!("value {:?}", c.value) }),
                Err(e) => return Err(CaptureError::NoExposure { path, reason: e.to_string() }),
            },
        };

        let mut stream = MmapStream::with_buffers(&device, BufType::VideoCapture, cfg.buffers.max(2))
            .map_err(io_err("VIDIOC_REQBUFS"))?;
        stream.set_timeout(cfg.poll_timeout);
        Ok(V4lCamera {
            path,
            stream,
            _device: device,
            converter,
            format,
            cfg,
            exposure_ns,
            seq: SeqCounter::default(),
            timestamp_source: None,
        })
    }

    /// The device node.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The format the driver set.
    pub fn format(&self) -> NegotiatedFormat {
        self.format
    }

    /// The timestamp source seen on the buffers so far (None before the first frame).
    pub fn timestamp_source(&self) -> Option<TimestampSource> {
        self.timestamp_source
    }
}

impl FrameSource for V4lCamera {
    fn frame_len(&self) -> usize {
        self.converter.dst_len()
    }

    fn next_frame(&mut self, mut gray: Vec<u8>) -> Result<Frame, CaptureError> {
        let (buf, meta) = match self.stream.next() {
            Ok(x) => x,
            Err(e) if e.kind() == io::ErrorKind::TimedOut => {
                return Err(CaptureError::Timeout { path: self.path.clone() })
            }
            Err(source) => return Err(CaptureError::Io { path: self.path.clone(), op: "VIDIOC_DQBUF", source }),
        };
        let flags = meta.flags.bits();
        let source = timestamp_source(flags).map_err(|clock| CaptureError::NotMonotonic {
            path: self.path.clone(),
            clock,
            flags,
        })?;
        self.timestamp_source = Some(source);
        if flags & BUF_FLAG_ERROR != 0 {
            return Err(CaptureError::Corrupt { path: self.path.clone(), seq: meta.sequence });
        }
        let used = if meta.bytesused == 0 { buf.len() } else { (meta.bytesused as usize).min(buf.len()) };
        gray.resize(self.converter.dst_len(), 0);
        self.converter.convert(&buf[..used], &mut gray).map_err(|source| CaptureError::Convert {
            path: self.path.clone(),
            seq: meta.sequence,
            source,
        })?;
        #[allow(clippy::useless_conversion)] // time_t is i32 on 32-bit ARM
        let stamp = timeval_to_ns(i64::from(meta.timestamp.sec), i64::from(meta.timestamp.usec));
        let (seq, _) = self.seq.step(meta.sequence);
        Ok(Frame {
            seq,
            t_start_ns: start_of_exposure_ns(stamp, source, self.exposure_ns, self.cfg.readout_ns, self.cfg.reference),
            exposure_ns: self.exposure_ns,
            readout_anchor: readout_anchor(source, self.cfg.reference),
            width: self.converter.width(),
            height: self.converter.height(),
            gray,
        })
    }
}

/// Counts of a stereo capture.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct StereoStats {
    /// Pairing counts (frames in, pairs, unpaired, out of order, driver drops from sequence gaps).
    pub pairing: PairStats,
    /// Frames lost to transient errors (corrupt buffer, conversion failure), left and right; they
    /// also show as sequence gaps in `pairing.dropped`.
    pub errors: [u64; 2],
}

type Delivery = (Side, Result<Frame, CaptureError>);

/// Two cameras, a capture thread each, paired in the caller's thread by [`StereoCapture::next_pair`].
pub struct StereoCapture {
    rx: Receiver<Delivery>,
    recycle: [SyncSender<Vec<u8>>; 2],
    stop: Arc<AtomicBool>,
    threads: Vec<JoinHandle<()>>,
    pairer: Pairer,
    errors: [u64; 2],
}

impl StereoCapture {
    /// Opens both devices with the same configuration and starts capturing.
    pub fn open(
        left: impl AsRef<Path>,
        right: impl AsRef<Path>,
        cfg: CaptureConfig,
        pairing: PairerConfig,
    ) -> Result<Self, CaptureError> {
        let l = V4lCamera::open(left, cfg.clone())?;
        let r = V4lCamera::open(right, cfg)?;
        Ok(Self::from_sources(l, r, pairing))
    }

    /// Starts a capture thread per source (any [`FrameSource`]: cameras, or stand-ins in tests).
    pub fn from_sources<L: FrameSource + 'static, R: FrameSource + 'static>(
        left: L,
        right: R,
        pairing: PairerConfig,
    ) -> Self {
        // Bounded: a consumer that stalls makes the threads wait (the driver then drops frames,
        // which the sequence numbers reveal) instead of growing a queue.
        let depth = 2 * pairing.window.max(1) + 2;
        let (tx, rx) = mpsc::sync_channel(depth);
        let stop = Arc::new(AtomicBool::new(false));
        let (rl, pool_l) = mpsc::sync_channel(depth);
        let (rr, pool_r) = mpsc::sync_channel(depth);
        let threads = vec![
            spawn_capture(Side::Left, left, tx.clone(), pool_l, stop.clone()),
            spawn_capture(Side::Right, right, tx, pool_r, stop.clone()),
        ];
        StereoCapture { rx, recycle: [rl, rr], stop, threads, pairer: Pairer::new(pairing), errors: [0; 2] }
    }

    /// The next pair, waiting at most `timeout` in all. Transient per-frame errors are counted and
    /// skipped; a camera that fails for good ends the capture with its error.
    pub fn next_pair(&mut self, timeout: Duration) -> Result<FramePair, CaptureError> {
        let deadline = std::time::Instant::now() + timeout;
        loop {
            let left = deadline.saturating_duration_since(std::time::Instant::now());
            let (side, res) = match self.rx.recv_timeout(left) {
                Ok(d) => d,
                Err(mpsc::RecvTimeoutError::Timeout) => {
                    return Err(CaptureError::Timeout { path: PathBuf::from("stereo pair") })
                }
                Err(mpsc::RecvTimeoutError::Disconnected) => return Err(CaptureError::Stopped),
            };
            match res {
                Ok(frame) => {
                    if let Some(pair) = self.pairer.push(side, frame) {
                        return Ok(pair);
                    }
                }
                Err(e) if e.is_transient() => self.errors[side.index()] += 1,
                Err(e) => return Err(e),
            }
        }
    }

    /// Gives a consumed pair's buffers back to the capture threads, so steady state does not allocate.
    pub fn recycle(&self, pair: FramePair) {
        let _ = self.recycle[0].try_send(pair.left.gray);
        let _ = self.recycle[1].try_send(pair.right.gray);
    }

    /// Pairing counts and each camera's errors so far.
    pub fn stats(&self) -> StereoStats {
        StereoStats { pairing: self.pairer.stats(), errors: self.errors }
    }
}

fn spawn_capture<S: FrameSource + 'static>(
    side: Side,
    mut source: S,
    tx: SyncSender<Delivery>,
    pool: Receiver<Vec<u8>>,
    stop: Arc<AtomicBool>,
) -> JoinHandle<()> {
    std::thread::Builder::new()
        .name(format!("capture-{side:?}").to_lowercase())
        .spawn(move || {
            while !stop.load(Ordering::Relaxed) {
                let gray = match pool.try_recv() {
                    Ok(buf) => buf,
                    Err(TryRecvError::Empty | TryRecvError::Disconnected) => Vec::with_capacity(source.frame_len()),
                };
                let res = source.next_frame(gray);
                if matches!(res, Err(CaptureError::Timeout { .. })) {
                    continue;
                }
                let fatal = matches!(&res, Err(e) if !e.is_transient());
                if tx.send((side, res)).is_err() || fatal {
                    break;
                }
            }
        })
        .expect("spawning a capture thread")
}

impl Drop for StereoCapture {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        // Unblock threads waiting on a full channel, then join them.
        while self.rx.try_recv().is_ok() {}
        for t in self.threads.drain(..) {
            while !t.is_finished() {
                while self.rx.try_recv().is_ok() {}
                std::thread::sleep(Duration::from_millis(1));
            }
            let _ = t.join();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn flags() {
        let mono = BUF_FLAG_TIMESTAMP_MONOTONIC;
        assert_eq!(timestamp_source(mono | BUF_FLAG_TSTAMP_SRC_SOE), Ok(TimestampSource::StartOfExposure));
        assert_eq!(timestamp_source(mono | BUF_FLAG_TSTAMP_SRC_EOF), Ok(TimestampSource::EndOfFrame));
        assert!(timestamp_source(BUF_FLAG_TIMESTAMP_COPY).is_err());
        assert!(timestamp_source(0).is_err());
    }

    #[test]
    fn seq_wraps() {
        let mut c = SeqCounter::default();
        assert_eq!(c.step(u32::MAX - 1), (u64::from(u32::MAX - 1), SeqStep::First));
        assert_eq!(c.step(u32::MAX), (u64::from(u32::MAX), SeqStep::Next));
        assert_eq!(c.step(2), (u64::from(u32::MAX) + 3, SeqStep::Gap(2)));
        assert_eq!(c.step(1), (u64::from(u32::MAX) + 3, SeqStep::Backwards));
    }
}
