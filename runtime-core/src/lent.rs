//! Buffers a writer lends for one message, and [`LentMap`], an array that lives either in its own memory
//! or inside such a buffer: the depth stage then writes the depth map ([`F32Map`]) and the cloud
//! ([`crate::messages::CloudMap`]) straight into the messages a sink will send (a ROS 2 Image and
//! PointCloud2 in Zenoh's shared memory), and every other sink reads that same memory, so neither is ever
//! copied into its message.
use std::any::Any;
use std::ops::{Deref, DerefMut};

/// A buffer lent by a writer's pool for one message. Dropping it gives it back to the pool.
pub trait LentBuf: Send {
    /// The message's bytes.
    fn bytes(&self) -> &[u8];
    /// The same, to write.
    fn bytes_mut(&mut self) -> &mut [u8];
    /// The buffer as its own type again, for the writer that lent it.
    fn into_any(self: Box<Self>) -> Box<dyn Any>;
}

/// Any owned byte buffer (Zenoh's `ZShmMut`, a `Vec<u8>`) can be lent.
impl<T: AsRef<[u8]> + AsMut<[u8]> + Send + 'static> LentBuf for T {
    fn bytes(&self) -> &[u8] {
        self.as_ref()
    }
    fn bytes_mut(&mut self) -> &mut [u8] {
        self.as_mut()
    }
    fn into_any(self: Box<Self>) -> Box<dyn Any> {
        self
    }
}

/// Values whose every bit pattern is valid and that have no padding, so that a message's bytes can be
/// read and written as them.
///
/// # Safety
/// Only for such types (plain `repr(C)` numbers).
pub unsafe trait Plain: Copy + Send + 'static {}

// SAFETY: any 4 bytes are an f32; no padding.
unsafe impl Plain for f32 {}

/// The map's values inside a lent message buffer.
struct Lent {
    buf: Box<dyn LentBuf>,
    /// Byte offset of the first value in the message.
    at: usize,
    /// Who lent it ([`LentMap::lend`]).
    owner: usize,
}

/// An array of `T` (a depth map, a cloud) that derefs to `[T]`: its own buffer, or, while a sink lends
/// one ([`LentMap::lend`]), the values' place in that sink's message. The own buffer is kept meanwhile, so
/// a map whose lent buffer is taken back or refused has its full size again without allocating (its values
/// are then stale: the map is filled every frame).
pub struct LentMap<T: Plain> {
    own: Vec<T>,
    lent: Option<Lent>,
}

/// A float map (the depth map).
pub type F32Map = LentMap<f32>;

impl<T: Plain> Default for LentMap<T> {
    fn default() -> Self {
        LentMap { own: Vec::new(), lent: None }
    }
}

impl<T: Plain> std::fmt::Debug for LentMap<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let lent = self.lent.as_ref().map(|l| l.owner);
        f.debug_struct("LentMap").field("len", &self.own.len()).field("lent_by", &lent).finish()
    }
}

impl<T: Plain> From<Vec<T>> for LentMap<T> {
    fn from(own: Vec<T>) -> Self {
        LentMap { own, lent: None }
    }
}

impl<T: Plain> LentMap<T> {
    /// Places the map's values in `buf` from byte `at` on, as many as the map has, for `owner` (any number
    /// the lender recognises its buffers by). Refused (the buffer is returned, the map stays in its own
    /// memory) when they do not fit or `at` is not aligned for `T` in memory. A buffer lent before is given
    /// back to its pool.
    pub fn lend(&mut self, buf: Box<dyn LentBuf>, at: usize, owner: usize) -> Result<(), Box<dyn LentBuf>> {
        self.lent = None;
        let need = at.checked_add(std::mem::size_of_val(&self.own[..]));
        let fits = need.is_some_and(|n| n <= buf.bytes().len());
        if !fits || buf.bytes()[at..].as_ptr().align_offset(std::mem::align_of::<T>()) != 0 {
            return Err(buf);
        }
        self.lent = Some(Lent { buf, at, owner });
        Ok(())
    }

    /// Who lent the buffer the values are in, if one did.
    pub fn lent_by(&self) -> Option<usize> {
        self.lent.as_ref().map(|l| l.owner)
    }

    /// Takes back the buffer `owner` lent (the values stay in it, the map goes back to its own memory).
    pub fn take_lent(&mut self, owner: usize) -> Option<Box<dyn LentBuf>> {
        if self.lent_by() != Some(owner) {
            return None;
        }
        self.lent.take().map(|l| l.buf)
    }

    /// Values the own buffer has room for without allocating.
    pub fn capacity(&self) -> usize {
        self.own.capacity()
    }

    /// The own buffer, to resize or refill (a lent buffer is given back first).
    pub fn vec_mut(&mut self) -> &mut Vec<T> {
        self.lent = None;
        &mut self.own
    }
}

impl<T: Plain> Deref for LentMap<T> {
    type Target = [T];

    fn deref(&self) -> &[T] {
        match &self.lent {
            None => &self.own,
            Some(l) => {
                let b = &l.buf.bytes()[l.at..l.at + std::mem::size_of_val(&self.own[..])];
                assert_eq!(b.as_ptr().align_offset(std::mem::align_of::<T>()), 0, "a lent buffer moved");
                // SAFETY: the bytes are aligned for T (checked), hold exactly `own.len()` values, borrowed
                // from `self`, and any bits are a valid T (`Plain`).
                unsafe { std::slice::from_raw_parts(b.as_ptr().cast::<T>(), self.own.len()) }
            }
        }
    }
}

impl<T: Plain> DerefMut for LentMap<T> {
    fn deref_mut(&mut self) -> &mut [T] {
        let n = self.own.len();
        match &mut self.lent {
            None => &mut self.own,
            Some(l) => {
                let b = &mut l.buf.bytes_mut()[l.at..l.at + n * std::mem::size_of::<T>()];
                assert_eq!(b.as_ptr().align_offset(std::mem::align_of::<T>()), 0, "a lent buffer moved");
                // SAFETY: as deref's, borrowed mutably from `self`.
                unsafe { std::slice::from_raw_parts_mut(b.as_mut_ptr().cast::<T>(), n) }
            }
        }
    }
}

impl<'a, T: Plain> IntoIterator for &'a LentMap<T> {
    type Item = &'a T;
    type IntoIter = std::slice::Iter<'a, T>;

    fn into_iter(self) -> Self::IntoIter {
        self.iter()
    }
}

impl<'a, T: Plain> IntoIterator for &'a mut LentMap<T> {
    type Item = &'a mut T;
    type IntoIter = std::slice::IterMut<'a, T>;

    fn into_iter(self) -> Self::IntoIter {
        self.iter_mut()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::atomic::{AtomicUsize, Ordering};
    use std::sync::Arc;

    /// A lent buffer (`len` bytes from `off` in its memory) that counts itself back to its pool when dropped.
    struct Counted {
        mem: Vec<u8>,
        off: usize,
        len: usize,
        back: Arc<AtomicUsize>,
    }
    impl AsRef<[u8]> for Counted {
        fn as_ref(&self) -> &[u8] {
            &self.mem[self.off..self.off + self.len]
        }
    }
    impl AsMut<[u8]> for Counted {
        fn as_mut(&mut self) -> &mut [u8] {
            &mut self.mem[self.off..self.off + self.len]
        }
    }
    impl Drop for Counted {
        fn drop(&mut self) {
            self.back.fetch_add(1, Ordering::Relaxed);
        }
    }

    /// A buffer of `len` bytes whose byte `at` is `skew` bytes past a 4-byte boundary.
    fn buffer(len: usize, at: usize, skew: usize, back: &Arc<AtomicUsize>) -> Box<dyn LentBuf> {
        let mem = vec![0u8; len + 8];
        let base = mem.as_ptr() as usize + at.min(len);
        let off = (4 - base % 4 + skew) % 4;
        Box::new(Counted { mem, off, len, back: back.clone() })
    }

    #[test]
    fn values_written_land_in_the_lent_message_and_read_back() {
        let back = Arc::new(AtomicUsize::new(0));
        let mut m = F32Map::from(vec![f32::NAN; 3]);
        m.lend(buffer(4 + 12 + 1, 4, 0, &back), 4, 7).map_err(|_| ()).unwrap();
        assert_eq!(m.lent_by(), Some(7));
        m.copy_from_slice(&[1.0, 2.0, 3.0]);
        assert_eq!(&m[..], [1.0, 2.0, 3.0]);
        // another owner cannot take it
        assert!(m.take_lent(8).is_none());
        let buf = m.take_lent(7).unwrap();
        assert_eq!(&buf.bytes()[4..16], [1.0f32, 2.0, 3.0].iter().flat_map(|v| v.to_le_bytes()).collect::<Vec<_>>());
        // the map is its own again, full size
        assert_eq!((m.lent_by(), m.len()), (None, 3));
        drop(buf);
        assert_eq!(back.load(Ordering::Relaxed), 1);
    }

    #[test]
    fn an_odd_or_short_buffer_is_refused_and_the_map_stays_its_own() {
        let back = Arc::new(AtomicUsize::new(0));
        let mut m = F32Map::from(vec![5.0; 3]);
        for skew in 1..4 {
            let Err(b) = m.lend(buffer(32, 4, skew, &back), 4, 1) else { panic!("misaligned: refused") };
            assert_ne!(b.bytes()[4..].as_ptr().align_offset(4), 0);
        }
        assert!(m.lend(buffer(4 + 11, 4, 0, &back), 4, 1).is_err(), "too short");
        assert!(m.lend(buffer(8, usize::MAX, 0, &back), usize::MAX, 1).is_err(), "offset overflows");
        assert_eq!((m.lent_by(), &m[..]), (None, &[5.0; 3][..]));
        // every refused buffer went back (dropped here)
        assert_eq!(back.load(Ordering::Relaxed), 5);
    }

    #[test]
    fn a_buffer_never_taken_back_returns_to_its_pool() {
        let back = Arc::new(AtomicUsize::new(0));
        let mut m = F32Map::from(vec![0.0; 2]);
        m.lend(buffer(8, 0, 0, &back), 0, 1).map_err(|_| ()).unwrap();
        // lending again (the next frame) gives the first back
        m.lend(buffer(8, 0, 0, &back), 0, 1).map_err(|_| ()).unwrap();
        assert_eq!(back.load(Ordering::Relaxed), 1);
        // reaching for the own buffer gives the second back
        m.vec_mut().push(1.0);
        assert_eq!((back.load(Ordering::Relaxed), m.len()), (2, 3));
        m.lend(buffer(12, 0, 0, &back), 0, 1).map_err(|_| ()).unwrap();
        drop(m);
        assert_eq!(back.load(Ordering::Relaxed), 3);
    }
}
