//! Where a frame's large messages (depth images, clouds, the confidence) are built: the output thread
//! writes the array straight into a message-sized buffer, at its place in the message, and the sink's
//! thread later writes the encoded fields around it ([`super::Encoded::encode`]). The array is copied once:
//! into a buffer lent by the writer ([`BufferPool`]: Zenoh's shared memory, which a subscriber on this
//! computer reads in place) or, when the writer has no pool or its pool is full, into the snapshot's own
//! buffer, reused from frame to frame (a file writer writes it as it is; Zenoh copies it into its batches).
//! The main depth image's and cloud's arrays are not copied at all when the pool lends: the depth stage
//! wrote them in the lent buffers ([`MessageBuf::expect_lent`], [`MessageBuf::adopt`]; `sinks::ros2_out`).
use std::sync::Arc;

pub use abvs_runtime_core::lent::LentBuf;

/// A writer's pool of message buffers, asked on the pipeline's output thread.
pub trait BufferPool: Send + Sync {
    /// A buffer of exactly `len` bytes, or `None`: the message goes in the snapshot's own buffer (a pool
    /// that is full counts it).
    fn lend(&self, len: usize) -> Option<Box<dyn LentBuf>>;
}

/// One large message's bytes as a writer receives them.
pub enum Payload<'a> {
    /// A small message, encoded on the sink's thread.
    Small(&'a [u8]),
    /// A large message in the snapshot's buffer, shared while the writer sends it (a writer that keeps
    /// it makes the next frame allocate a new one).
    Shared(SharedMessage),
    /// A large message in a buffer the writer's pool lent: its first `usize` bytes (a cloud's buffer is lent
    /// for every pixel, before the depth stage knows how many points it has).
    Lent(Box<dyn LentBuf>, usize),
}

impl Payload<'_> {
    /// The message's bytes.
    pub fn bytes(&self) -> &[u8] {
        match self {
            Payload::Small(b) => b,
            Payload::Shared(s) => s.as_ref(),
            Payload::Lent(l, n) => &l.bytes()[..*n],
        }
    }
}

/// The snapshot's buffer of a large message, shared with a writer (`AsRef<[u8]>`, as `bytes` takes it).
#[derive(Debug, Clone)]
pub struct SharedMessage(Arc<Vec<u8>>);

impl AsRef<[u8]> for SharedMessage {
    fn as_ref(&self) -> &[u8] {
        &self.0
    }
}

/// A large message's place: `head` bytes of fields, the array, `tail` bytes of fields.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Layout {
    /// Bytes before the array (the encapsulation and the fields, the array's length last).
    pub head: usize,
    /// The array's bytes.
    pub array: usize,
    /// Bytes after it.
    pub tail: usize,
}

impl Layout {
    /// Bytes of the whole message.
    pub fn len(&self) -> usize {
        self.head + self.array + self.tail
    }

    /// Whether the message has no bytes (never: every message has its encapsulation).
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// A large message being built: in a lent buffer or the snapshot's own.
#[derive(Default)]
pub struct MessageBuf {
    own: Arc<Vec<u8>>,
    lent: Option<Box<dyn LentBuf>>,
    layout: Layout,
    /// Waiting for the buffer its array was written in ([`MessageBuf::expect_lent`]).
    expecting: bool,
}

impl std::fmt::Debug for MessageBuf {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("MessageBuf").field("layout", &self.layout).field("lent", &self.lent.is_some()).finish()
    }
}

impl Clone for MessageBuf {
    /// A copy in a buffer of its own (a lent buffer is the writer's, once).
    fn clone(&self) -> MessageBuf {
        MessageBuf { own: Arc::new(self.message().to_vec()), lent: None, layout: self.layout, expecting: false }
    }
}

impl MessageBuf {
    /// Readies the buffer for a message of `layout` and returns the array's bytes to write: a buffer of
    /// `pool` when it lends one, else the snapshot's own (a new one, counted in `replaced`, when a writer
    /// still holds the last). The fields around the array are written later ([`MessageBuf::fields_mut`]).
    pub fn array_mut(&mut self, layout: Layout, pool: Option<&dyn BufferPool>, replaced: &mut u32) -> &mut [u8] {
        (self.layout, self.expecting) = (layout, false);
        // a buffer lent for an earlier frame that was not sent (dropped, skipped) goes back to its pool
        self.lent = pool.and_then(|p| p.lend(layout.len()));
        let msg = match &mut self.lent {
            Some(l) => l.bytes_mut(),
            None => {
                if Arc::get_mut(&mut self.own).is_none() {
                    self.own = Arc::default();
                    *replaced += 1;
                }
                let own = Arc::make_mut(&mut self.own);
                // grows zeroed, shrinks without a write; the array is written over next
                own.resize(layout.len(), 0);
                own
            }
        };
        &mut msg[layout.head..layout.head + layout.array]
    }

    /// The message's layout.
    pub fn layout(&self) -> Layout {
        self.layout
    }

    /// The whole message (its fields as last written).
    pub fn message(&self) -> &[u8] {
        match &self.lent {
            Some(l) => &l.bytes()[..self.layout.len()],
            None => &self.own[..self.layout.len()],
        }
    }

    /// The array's bytes.
    pub fn array(&self) -> &[u8] {
        &self.message()[self.layout.head..self.layout.head + self.layout.array]
    }

    /// The places of the fields before and after the array, to write.
    pub fn fields_mut(&mut self) -> (&mut [u8], &mut [u8]) {
        let Layout { head, array, .. } = self.layout;
        let msg = match &mut self.lent {
            Some(l) => &mut l.bytes_mut()[..self.layout.len()],
            None => &mut Arc::make_mut(&mut self.own)[..self.layout.len()],
        };
        let (h, rest) = msg.split_at_mut(head);
        (h, &mut rest[array..])
    }

    /// Readies the buffer for a message of `layout` whose array is already written in a buffer lent for it
    /// elsewhere (the depth map's or the cloud's, [`abvs_runtime_core::lent::LentMap::lend`]), which comes
    /// with [`MessageBuf::adopt`]; until then the buffer has no message.
    pub fn expect_lent(&mut self, layout: Layout) {
        (self.layout, self.expecting) = (layout, true);
        self.lent = None;
    }

    /// Whether the message waits for its lent buffer ([`MessageBuf::expect_lent`]).
    pub fn expecting(&self) -> bool {
        self.expecting
    }

    /// Takes the lent buffer that holds this message's array, after [`MessageBuf::expect_lent`]: the message
    /// is its first `layout.len()` bytes (a cloud's buffer was lent for more points than the frame has); a
    /// shorter buffer is returned.
    pub fn adopt(&mut self, buf: Box<dyn LentBuf>) -> Result<(), Box<dyn LentBuf>> {
        if buf.bytes().len() < self.layout.len() {
            return Err(buf);
        }
        (self.lent, self.expecting) = (Some(buf), false);
        Ok(())
    }

    /// The message for a writer: the lent buffer itself (this one no longer has it), or the own one shared.
    pub fn payload(&mut self) -> Payload<'static> {
        match self.lent.take() {
            Some(l) => Payload::Lent(l, self.layout.len()),
            None => Payload::Shared(SharedMessage(Arc::clone(&self.own))),
        }
    }

    /// Gives a lent buffer that was not sent back to its pool.
    pub fn release(&mut self) {
        (self.lent, self.expecting) = (None, false);
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use std::sync::atomic::{AtomicUsize, Ordering};

    /// A pool of plain memory that lends `left` buffers, then none.
    pub(crate) struct VecPool {
        pub left: AtomicUsize,
    }

    impl BufferPool for VecPool {
        fn lend(&self, len: usize) -> Option<Box<dyn LentBuf>> {
            let left = self.left.load(Ordering::Relaxed);
            (left > 0).then(|| {
                self.left.store(left - 1, Ordering::Relaxed);
                // not zeroed, as a shared-memory buffer from a pool is not
                Box::new(vec![0xa5u8; len]) as Box<dyn LentBuf>
            })
        }
    }

    #[test]
    fn lent_or_own_the_message_is_the_same() {
        let pool = VecPool { left: AtomicUsize::new(1) };
        let layout = Layout { head: 3, array: 4, tail: 1 };
        let mut out = Vec::new();
        let mut replaced = 0;
        for _ in 0..3 {
            let mut b = MessageBuf::default();
            b.array_mut(layout, Some(&pool), &mut replaced).copy_from_slice(&[1, 2, 3, 4]);
            let (h, t) = b.fields_mut();
            h.copy_from_slice(&[7, 8, 9]);
            t.copy_from_slice(&[5]);
            assert_eq!(b.array(), [1, 2, 3, 4]);
            let p = b.payload();
            out.push((matches!(p, Payload::Lent(..)), p.bytes().to_vec()));
        }
        // the first from the pool, then (pool empty) the own buffer: the same bytes
        assert_eq!(out.iter().map(|o| o.0).collect::<Vec<_>>(), [true, false, false]);
        assert!(out.iter().all(|o| o.1 == [7, 8, 9, 1, 2, 3, 4, 5]));
        assert_eq!(replaced, 0);
    }

    #[test]
    fn an_adopted_buffer_is_the_message_and_a_short_one_is_refused() {
        let layout = Layout { head: 2, array: 4, tail: 1 };
        let mut b = MessageBuf::default();
        b.expect_lent(layout);
        assert!(b.expecting());
        assert!(b.adopt(Box::new(vec![0u8; 6])).is_err());
        // the array as the depth stage wrote it in the lent buffer, the fields written around it; the buffer
        // lent for a longer array (a cloud's, for every pixel) ends where the message does
        b.adopt(Box::new(vec![0, 0, 1, 2, 3, 4, 0, 0xa5, 0xa5])).map_err(|_| ()).unwrap();
        assert!(!b.expecting());
        let (h, t) = b.fields_mut();
        h.copy_from_slice(&[8, 9]);
        t.copy_from_slice(&[7]);
        assert_eq!(b.array(), [1, 2, 3, 4]);
        assert_eq!(b.message(), [8, 9, 1, 2, 3, 4, 7]);
        let p = b.payload();
        assert!(matches!(p, Payload::Lent(_, 7)));
        assert_eq!(p.bytes(), [8, 9, 1, 2, 3, 4, 7]);
    }

    #[test]
    fn a_held_buffer_is_replaced_and_counted() {
        let mut b = MessageBuf::default();
        let mut replaced = 0;
        let layout = Layout { head: 1, array: 2, tail: 0 };
        b.array_mut(layout, None, &mut replaced).copy_from_slice(&[1, 2]);
        let held = b.payload();
        b.array_mut(layout, None, &mut replaced).copy_from_slice(&[3, 4]);
        assert_eq!(replaced, 1);
        // the writer still has the first frame's bytes
        assert_eq!(&held.bytes()[1..], [1, 2]);
        drop(held);
        b.array_mut(Layout { head: 1, array: 4, tail: 2 }, None, &mut replaced);
        assert_eq!((replaced, b.message().len()), (1, 7));
    }
}
