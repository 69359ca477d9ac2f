//! The publishing side: loans, the caller's fill through a [`SampleWriter`], send and notify.
use super::*;

/// What a publisher saw that was not a plain delivery. None of it makes a publish fail.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Serialize)]
pub struct PublishStats {
    /// Samples sent.
    pub published: u64,
    /// Sum over samples of the subscribers each was delivered to.
    pub deliveries: u64,
    /// Samples not sent because no shared-memory sample could be loaned (should stay 0 with the sizing).
    pub loan_failures: u64,
    /// Sends that reported a broken connection (e.g. a subscriber that died).
    pub send_failures: u64,
    /// Event notifications that failed.
    pub notify_failures: u64,
    /// Dead nodes (crashed processes) whose resources were removed.
    pub dead_nodes_cleaned: u64,
}

/// Publishes one topic: [`DepthPublisher`], [`CloudPublisher`] or the confidence ([`Publisher::confidence`]).
/// Create once at start-up.
pub struct Publisher<T: BridgePayload> {
    service: String,
    max: usize,
    /// Written into the elements a fill leaves (the payload's [`BridgePayload::INVALID`], or the topic's).
    invalid: T,
    stats: PublishStats,
    // field order is drop order: ports before the services and the node
    publisher: IoxPublisher<Ipc, [T], FrameHeader>,
    notifier: Notifier<Ipc>,
    _pubsub: PubSubFactory<T>,
    _event: EventFactory,
    node: Node<Ipc>,
}

/// Depth maps on `{prefix}/depth`.
pub type DepthPublisher = Publisher<f32>;
/// Point clouds on `{prefix}/cloud`.
pub type CloudPublisher = Publisher<CloudPoint>;

impl<T: BridgePayload> Publisher<T> {
    /// Opens (or creates) the topic's services with `config` and a publisher sized for
    /// `config.max_width x config.max_height` elements.
    pub fn new(config: &BridgeConfig) -> Result<Self, BridgeError> {
        Self::for_topic(config, T::TOPIC, T::INVALID)
    }

    /// A publisher of `T` on another topic than the payload's own (`{prefix}/{topic}`), elements a fill
    /// leaves set to `invalid`.
    /// The fovea's service of this payload: `{prefix}/fovea/depth` or `{prefix}/fovea/cloud` ([`FOVEA_TOPIC`]);
    /// `config` sized for the fovea's window.
    pub fn fovea(config: &BridgeConfig) -> Result<Self, BridgeError> {
        Self::for_topic(config, &format!("{FOVEA_TOPIC}/{}", T::TOPIC), T::INVALID)
    }

    pub(super) fn for_topic(config: &BridgeConfig, topic: &str, invalid: T) -> Result<Self, BridgeError> {
        config.check()?;
        let service = config.service_name(topic);
        check_shm_space(&service, config.publisher_bytes::<T>())?;
        let (node, cleaned) = node(config, topic)?;
        let (pubsub, event) = open_services::<T>(&node, config, topic)?;
        let max = config.max_elements();
        let publisher = pubsub
            .publisher_builder()
            .initial_max_slice_len(max)
            .allocation_strategy(AllocationStrategy::Static)
            .max_loaned_samples(1)
            .backpressure_strategy(BackpressureStrategy::DiscardData)
            .create()
            .map_err(|e| match e {
                iceoryx2::port::publisher::PublisherCreateError::ExceedsMaxSupportedPublishers => {
                    BridgeError::PublisherTaken { service: service.clone(), holders: publisher_holders(&pubsub) }
                }
                e => iox(&service, "creating the publisher")(e),
            })?;
        let notifier = event.notifier_builder().create().map_err(iox(&service, "creating the event notifier"))?;
        let stats = PublishStats { dead_nodes_cleaned: cleaned, ..Default::default() };
        Ok(Self { service, max, invalid, stats, publisher, notifier, _pubsub: pubsub, _event: event, node })
    }

    /// The publish-subscribe service's name.
    pub fn service_name(&self) -> &str {
        &self.service
    }

    /// Largest number of elements in one sample.
    pub fn capacity(&self) -> usize {
        self.max
    }

    /// What was counted so far.
    pub fn stats(&self) -> PublishStats {
        self.stats
    }

    /// Loans `n_max` elements, lets `fill` append to the front of them through a [`SampleWriter`], writes
    /// the topic's invalid value ([`BridgePayload::INVALID`] but for the confidence, 0) into the rest, sets `header` (with `t_publish_ns` = now) as the user header,
    /// sends and notifies. Returns the number of subscribers the sample was delivered to. With
    /// `valid_from_fill`, `header.valid` becomes the number of elements written.
    pub(super) fn publish_impl<F>(
        &mut self,
        header: &FrameHeader,
        n_max: usize,
        valid_from_fill: bool,
        fill: F,
    ) -> Result<usize, BridgeError>
    where
        F: FnOnce(&mut SampleWriter<'_, T>),
    {
        if n_max > self.max {
            return Err(BridgeError::TooLarge { service: self.service.clone(), n: n_max, max: self.max });
        }
        let mut sample = match self.publisher.loan_slice_uninit(n_max) {
            Ok(s) => s,
            Err(LoanError::OutOfMemory) | Err(LoanError::ExceedsMaxLoans) => {
                self.stats.loan_failures += 1;
                return Ok(0);
            }
            Err(e) => return Err(iox(&self.service, "loaning a sample")(e)),
        };
        let payload = sample.payload_mut();
        let base = payload.as_ptr();
        let mut writer = SampleWriter { buf: payload, len: 0, overflow: false };
        fill(&mut writer);
        let SampleWriter { buf, len: n, overflow } = writer;
        // The writer is the only way in and cannot be built outside this module; the pointer check makes sure
        // the one handed back is the one handed out (not another publish's, swapped in by a nested call).
        if overflow || !std::ptr::eq(buf.as_ptr(), base) || buf.len() != n_max || n > n_max {
            return Err(BridgeError::Overflow { service: self.service.clone(), capacity: n_max });
        }
        for p in &mut buf[n..] {
            p.write(self.invalid);
        }
        // SAFETY: the writer wrote [..n] (it advances its count only after a `MaybeUninit::write`), the loop
        // above [n..]; both on this sample's payload (checked above).
        let mut sample = unsafe { sample.assume_init() };
        let uh = sample.user_header_mut();
        *uh = *header;
        if valid_from_fill {
            uh.valid = n as u32;
        }
        uh.t_publish_ns = monotonic_ns();
        let delivered = match sample.send() {
            Ok(k) => k,
            Err(_) => {
                self.stats.send_failures += 1;
                0
            }
        };
        self.stats.published += 1;
        self.stats.deliveries += delivered as u64;
        if self.notifier.notify().is_err() {
            self.stats.notify_failures += 1;
        }
        Ok(delivered)
    }

    /// Delivers the history to subscribers that joined since the last send and wakes them. The
    /// publisher does this on every send; call it when no sample is due for a while.
    pub fn update_connections(&mut self) -> Result<(), BridgeError> {
        self.publisher.update_connections().map_err(iox(&self.service, "updating connections"))?;
        if self.notifier.notify().is_err() {
            self.stats.notify_failures += 1;
        }
        Ok(())
    }

    /// Removes the resources of dead nodes (crashed or killed processes) on this machine; returns how many.
    /// Done at start-up; call it now and then (e.g. once a second) in a long run.
    pub fn cleanup_dead_nodes(&mut self) -> u64 {
        let n = self.node.try_cleanup_dead_nodes().cleanups;
        self.stats.dead_nodes_cleaned += n;
        n
    }
}

/// Where a publish's fill writes: the front of the loaned shared-memory slice, one element after the other.
/// It counts what was written; the publisher sends every element it did not write as
/// [`BridgePayload::INVALID`]. Only the publisher makes one.
///
/// The count is the writer's, so a fill cannot claim elements it did not write (the misuse the previous
/// API allowed, a fill that reports 100 points and writes none, does not compile):
/// ```compile_fail
/// # use abvs_runtime::bridges::iceoryx::*;
/// # fn f(p: &mut CloudPublisher, h: &FrameHeader) {
/// p.publish_cloud(h, 100, |_| 100).unwrap();
/// # }
/// ```
/// and a writer cannot be made outside the publisher:
/// ```compile_fail
/// # use abvs_runtime::bridges::iceoryx::*;
/// let mut buf = [std::mem::MaybeUninit::<f32>::uninit(); 4];
/// let w = SampleWriter { buf: &mut buf[..], len: 4, overflow: false };
/// ```
/// while this is how a fill writes:
/// ```no_run
/// # use abvs_runtime::bridges::iceoryx::*;
/// # fn f(p: &mut CloudPublisher, h: &FrameHeader, pts: &[CloudPoint]) {
/// p.publish_cloud(h, pts.len(), |w| w.extend_from_slice(pts)).unwrap();
/// # }
/// ```
pub struct SampleWriter<'a, T> {
    buf: &'a mut [MaybeUninit<T>],
    len: usize,
    overflow: bool,
}

impl<T: Copy> SampleWriter<'_, T> {
    /// Elements the sample holds.
    pub fn capacity(&self) -> usize {
        self.buf.len()
    }

    /// Elements written so far.
    pub fn len(&self) -> usize {
        self.len
    }

    /// Whether nothing was written yet.
    pub fn is_empty(&self) -> bool {
        self.len == 0
    }

    /// Appends one element. Past the capacity nothing is written, `false` is returned and the publish fails
    /// with [`BridgeError::Overflow`] (nothing is sent).
    #[inline]
    pub fn push(&mut self, v: T) -> bool {
        match self.buf.get_mut(self.len) {
            Some(slot) => {
                slot.write(v);
                self.len += 1;
                true
            }
            None => {
                self.overflow = true;
                false
            }
        }
    }

    /// Appends all of `src`. What does not fit is not written and makes the publish fail, as [`Self::push`].
    pub fn extend_from_slice(&mut self, src: &[T]) {
        let room = self.buf.len() - self.len;
        if src.len() > room {
            self.overflow = true;
        }
        let n = src.len().min(room);
        for (d, s) in self.buf[self.len..self.len + n].iter_mut().zip(src) {
            d.write(*s);
        }
        self.len += n;
    }
}

impl Publisher<f32> {
    /// The confidence publisher on `{prefix}/confidence` ([`CONFIDENCE_TOPIC`]): `[f32]` in [0, 1] per depth
    /// pixel, 0 = invalid (also every element a fill leaves), sent with [`Publisher::publish_depth`] and
    /// the depth map's header.
    pub fn confidence(config: &BridgeConfig) -> Result<Self, BridgeError> {
        Self::for_topic(config, CONFIDENCE_TOPIC, 0.0)
    }

    /// Publishes a depth map of `header.width x header.height` (row-major, metres, NaN = invalid), or on the
    /// confidence topic the confidence map: `fill` writes it through the [`SampleWriter`] into the loaned
    /// shared memory (elements not written are NaN, confidence 0). `header.valid` is sent as given.
    pub fn publish_depth<F>(&mut self, header: &FrameHeader, fill: F) -> Result<usize, BridgeError>
    where
        F: FnOnce(&mut SampleWriter<'_, f32>),
    {
        let n = (header.width as usize).saturating_mul(header.height as usize);
        if n > self.max {
            return Err(BridgeError::BadSize {
                service: self.service.clone(),
                width: header.width,
                height: header.height,
                max: self.max,
            });
        }
        self.publish_impl(header, n, false, fill)
    }
}

impl Publisher<CloudPoint> {
    /// Publishes a cloud of at most `n_max` points (at most the header's organised `width x height`): `fill`
    /// writes the valid points through the [`SampleWriter`] to the front of the loaned shared-memory slice
    /// (`header.valid` is set to how many it wrote). The sample carries `n_max` elements, the unused tail
    /// set to NaN: pass the exact count when it is known (e.g. the valid depth pixels) to save that fill.
    pub fn publish_cloud<F>(&mut self, header: &FrameHeader, n_max: usize, fill: F) -> Result<usize, BridgeError>
    where
        F: FnOnce(&mut SampleWriter<'_, CloudPoint>),
    {
        let organised = (header.width as usize).saturating_mul(header.height as usize);
        if n_max > organised {
            return Err(BridgeError::TooLarge { service: self.service.clone(), n: n_max, max: organised });
        }
        self.publish_impl(header, n_max, true, fill)
    }
}
