//! The receiving side: samples checked against their headers, waiting on the event service.
use super::*;

/// What a subscriber saw.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct SubscribeStats {
    /// Samples received.
    pub received: u64,
    /// Gaps in `seq` between consecutive samples (dropped by safe overflow or not published).
    pub seq_gaps: u64,
    /// Samples whose `seq` is not after the previous one's: a publisher that restarted (its sequence starts
    /// again) while this subscriber stayed up.
    pub seq_restarts: u64,
    /// Dead nodes whose resources were removed when this subscriber started.
    pub dead_nodes_cleaned: u64,
    /// Samples dropped because the payload did not fit the header (not `width x height` depth values, a
    /// cloud longer than `width x height` or shorter than `valid`).
    pub malformed: u64,
}

/// One received sample: the header and the payload, read in place in shared memory. Dropping it returns
/// the sample to the publisher; hold at most `subscriber_max_borrowed` (2) at a time.
pub struct Received<T: BridgePayload> {
    sample: Sample<Ipc, [T], FrameHeader>,
}

impl<T: BridgePayload> Received<T> {
    /// The frame header.
    pub fn header(&self) -> &FrameHeader {
        self.sample.user_header()
    }

    /// The payload: the whole depth map (width x height), or the cloud's valid points.
    pub fn data(&self) -> &[T] {
        let p = self.sample.payload();
        if T::TRIM_TO_VALID {
            &p[..(self.header().valid as usize).min(p.len())]
        } else {
            p
        }
    }
}

/// Whether a received payload of `len` elements fits its header: depth `width x height` exactly, a cloud at
/// most that and at least `valid`.
pub fn payload_fits<T: BridgePayload>(h: &FrameHeader, len: usize) -> bool {
    let Some(organised) = (h.width as usize).checked_mul(h.height as usize) else { return false };
    let valid_ok = (h.valid as usize) <= len;
    if T::TRIM_TO_VALID {
        valid_ok && len <= organised
    } else {
        valid_ok && len == organised
    }
}

/// Receives one topic: [`DepthSubscriber`], [`CloudSubscriber`] or the confidence
/// ([`Subscriber::confidence`]).
pub struct Subscriber<T: BridgePayload> {
    service: String,
    stats: SubscribeStats,
    last_seq: Option<u64>,
    subscriber: IoxSubscriber<Ipc, [T], FrameHeader>,
    listener: Listener<Ipc>,
    _pubsub: PubSubFactory<T>,
    _event: EventFactory,
    _node: Node<Ipc>,
}

/// Depth maps from `{prefix}/depth`.
pub type DepthSubscriber = Subscriber<f32>;
/// Point clouds from `{prefix}/cloud`.
pub type CloudSubscriber = Subscriber<CloudPoint>;

impl Subscriber<f32> {
    /// Receives the confidence maps of `{prefix}/confidence` ([`CONFIDENCE_TOPIC`]): `width x height` values in
    /// [0, 1] per sample (0 = invalid), with the header of the depth map of the same `seq`.
    pub fn confidence(config: &BridgeConfig) -> Result<Self, BridgeError> {
        Self::for_topic(config, CONFIDENCE_TOPIC)
    }
}

impl<T: BridgePayload> Subscriber<T> {
    /// Opens (or creates, if no publisher is there yet) the topic's services with `config`.
    pub fn new(config: &BridgeConfig) -> Result<Self, BridgeError> {
        Self::for_topic(config, T::TOPIC)
    }

    /// Opens the fovea's service of this payload (`{prefix}/fovea/depth`, `{prefix}/fovea/cloud`).
    pub fn fovea(config: &BridgeConfig) -> Result<Self, BridgeError> {
        Self::for_topic(config, &format!("{FOVEA_TOPIC}/{}", T::TOPIC))
    }

    fn for_topic(config: &BridgeConfig, topic: &str) -> Result<Self, BridgeError> {
        config.check()?;
        let service = config.service_name(topic);
        let (node, cleaned) = node(config, topic)?;
        let (pubsub, event) = open_services::<T>(&node, config, topic)?;
        let subscriber = pubsub
            .subscriber_builder()
            .buffer_size(config.subscriber_buffer)
            .create()
            .map_err(iox(&service, "creating the subscriber"))?;
        let listener = event.listener_builder().create().map_err(iox(&service, "creating the event listener"))?;
        let stats = SubscribeStats { dead_nodes_cleaned: cleaned, ..Default::default() };
        Ok(Self { service, stats, last_seq: None, subscriber, listener, _pubsub: pubsub, _event: event, _node: node })
    }

    /// The publish-subscribe service's name.
    pub fn service_name(&self) -> &str {
        &self.service
    }

    /// What was counted so far.
    pub fn stats(&self) -> SubscribeStats {
        self.stats
    }

    /// Takes the next sample without waiting. A sample whose payload does not fit its header is dropped
    /// and counted ([`SubscribeStats::malformed`]); the next one is taken instead.
    pub fn try_receive(&mut self) -> Result<Option<Received<T>>, BridgeError> {
        loop {
            let Some(sample) = self.subscriber.receive().map_err(iox(&self.service, "receiving"))? else {
                return Ok(None);
            };
            let h = sample.user_header();
            if !payload_fits::<T>(h, sample.payload().len()) {
                self.stats.malformed += 1;
                continue;
            }
            let seq = h.seq;
            if let Some(last) = self.last_seq {
                if seq > last.saturating_add(1) {
                    self.stats.seq_gaps += 1;
                } else if seq <= last {
                    self.stats.seq_restarts += 1;
                }
            }
            self.last_seq = Some(seq);
            self.stats.received += 1;
            return Ok(Some(Received { sample }));
        }
    }

    /// Waits up to `timeout` for the next sample, asleep on the event service between samples.
    /// `Ok(None)`: nothing arrived in time.
    pub fn wait(&mut self, timeout: Duration) -> Result<Option<Received<T>>, BridgeError> {
        let deadline = Instant::now() + timeout;
        loop {
            if let Some(r) = self.try_receive()? {
                // consume the notification(s) of what is being taken now
                let _ = self.listener.try_wait(|_| {});
                return Ok(Some(r));
            }
            let now = Instant::now();
            if now >= deadline {
                return Ok(None);
            }
            // A notification that came after the receive above is kept by the listener, so the wait returns
            // at once. The 100 ms cap only bounds the delay of a late joiner's history (delivered by the
            // publisher without a notification if it calls no update_connections).
            let slice = (deadline - now).min(Duration::from_millis(100));
            self.listener.timed_wait(|_| {}, slice).map_err(iox(&self.service, "waiting on the event listener"))?;
        }
    }
}
