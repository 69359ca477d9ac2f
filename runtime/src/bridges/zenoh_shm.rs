//! The Zenoh writer's shared-memory pool (`[bridges.zenoh] shared_memory`, the default): the pipeline's
//! output thread writes each large message's array straight into one of its buffers
//! ([`crate::ros2::buffers`]), the sink's thread writes the fields around it and puts the buffer as it is. A
//! subscriber on this computer whose session enables shared memory receives a descriptor of the buffer,
//! not the bytes; any other gets the same bytes, which Zenoh copies out of it. When the pool has no free
//! buffer (subscribers still hold them) the message goes in the snapshot's own buffer, the ordinary way
//! (counted: `shm_fallbacks`), so the pool never blocks the pipeline.
use std::num::NonZeroUsize;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Mutex;

use ::zenoh::bytes::ZBytes;
use ::zenoh::shm::{
    AllocAlignment, GarbageCollect, OwnedShmBuf, PosixShmProviderBackend, ShmProvider, ShmProviderBuilder, ZShmMut,
};
use ::zenoh::Wait;

use crate::ros2::buffers::{BufferPool, LentBuf};

/// Messages this large and larger go through shared memory: the depth images and the clouds; a smaller
/// one (CameraInfo, /tf, JointState: < 1 KiB; a cloud of few points) fits one of Zenoh's 64 KiB batches
/// and costs less copied than a buffer's bookkeeping.
pub const SHM_MIN_BYTES: usize = 64 * 1024;

/// The pool holds this many of the first large message (the main depth image: a frame's large messages
/// take about seven and a half of it, the cloud's buffer lent for every pixel at 16 bytes a point against
/// the image's 4, plus the confidence and the fovea's: 40 hold about five frames, for a subscriber that
/// copies each sample out before it lets go; 16 fell back to the ordinary path for 3 % of the messages with
/// such a Python subscriber when the cloud took only its points).
const SHM_POOL_MESSAGES: usize = 40;

/// The pool, made at the first large message: `SHM_POOL_MESSAGES` times its size (at least 32 MiB).
#[derive(Default)]
pub struct ShmPool {
    state: Mutex<State>,
    fallbacks: AtomicU64,
}

#[derive(Default)]
struct State {
    provider: Option<ShmProvider<PosixShmProviderBackend>>,
    /// Why the pool could not be made (then every message goes the ordinary way).
    failed: Option<String>,
    bytes: usize,
}

impl BufferPool for ShmPool {
    fn lend(&self, len: usize) -> Option<Box<dyn LentBuf>> {
        if len < SHM_MIN_BYTES {
            return None;
        }
        let mut st = self.state.lock().unwrap_or_else(|e| e.into_inner());
        if st.provider.is_none() && st.failed.is_none() {
            let size = (SHM_POOL_MESSAGES * len).max(32 << 20).next_multiple_of(4);
            // every buffer 4-byte aligned (the default is 1): the depth stage writes its float map in place
            // (`F32Map::lend` refuses a misaligned buffer), the cloud is packed as words. (The provider rounds
            // each buffer's room up to 4 bytes; its length stays the one asked.)
            match ShmProviderBuilder::default_backend((size, AllocAlignment::ALIGN_4_BYTES)).wait() {
                Ok(p) => (st.provider, st.bytes) = (Some(p), size),
                Err(e) => st.failed = Some(e.to_string()),
            }
        }
        // GarbageCollect: when the pool is full, reclaim the buffers subscribers let go and try once more;
        // never waits
        match st.provider.as_ref()?.alloc(len).with_policy::<GarbageCollect>().wait() {
            Ok(buf) => Some(Box::new(buf)),
            Err(_) => {
                self.fallbacks.fetch_add(1, Ordering::Relaxed);
                None
            }
        }
    }
}

impl ShmPool {
    /// What the pool did, for the writer's stats: messages it lent buffers for come from the writer.
    pub fn report(&self, messages: u64) -> serde_json::Value {
        let st = self.state.lock().unwrap_or_else(|e| e.into_inner());
        serde_json::json!({
            "shared_memory": true,
            "shm_messages": messages,
            "shm_fallbacks": self.fallbacks.load(Ordering::Relaxed),
            "shm_pool_bytes": st.bytes,
            "shm_error": st.failed,
        })
    }
}

/// The first `len` bytes of a buffer this pool lent, as a sample's payload (`None`: another pool's, or
/// `len` more than it holds). (A cloud's buffer is lent for every pixel and sent shortened to its points:
/// the shared memory stays the buffer's, only the length the subscriber sees changes.)
pub fn payload(buf: Box<dyn LentBuf>, len: usize) -> Option<ZBytes> {
    let mut b = buf.into_any().downcast::<ZShmMut>().ok()?;
    if len != b.len() {
        b.try_resize(NonZeroUsize::new(len)?)?;
    }
    Some(ZBytes::from(*b))
}
