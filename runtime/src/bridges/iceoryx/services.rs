//! Nodes and services: creating and opening them with exactly the bridge's settings, who holds them,
//! /dev/shm space, dead nodes of crashed processes.
use super::*;

pub(super) fn iox<'a, E: Debug>(service: &'a str, what: &'static str) -> impl FnOnce(E) -> BridgeError + 'a {
    move |e| BridgeError::Iceoryx { service: service.to_string(), what, detail: format!("{e:?}") }
}

pub(super) fn node(cfg: &BridgeConfig, role: &str) -> Result<(Node<Ipc>, u64), BridgeError> {
    // iceoryx2 warns on every start that no config file was loaded (its defaults are what we use);
    // errors only, unless IOX2_LOG_LEVEL says otherwise
    static LOG_LEVEL: std::sync::Once = std::sync::Once::new();
    LOG_LEVEL.call_once(|| set_log_level_from_env_or(LogLevel::Error));
    let service = cfg.service_name(role);
    let name = NodeName::new(&format!("abvs-{role}")).map_err(iox(&service, "naming the node"))?;
    // iceoryx2 would remove dead nodes inside `create` without saying how many: that is done below instead,
    // counted (the counts are in PublishStats and SubscribeStats)
    let mut config = Config::global_config().clone();
    config.global.node.cleanup_dead_nodes_on_creation = false;
    let node = NodeBuilder::new()
        .config(&config)
        .name(&name)
        // a library must not take over SIGINT/SIGTERM from the program it runs in
        .signal_handling_mode(SignalHandlingMode::Disabled)
        .create::<Ipc>()
        .map_err(iox(&service, "creating the iceoryx2 node"))?;
    // resources of processes that died (killed, crashed) are removed here, so a restart works
    let cleaned = node.try_cleanup_dead_nodes().cleanups;
    Ok((node, cleaned))
}

/// Where POSIX shared memory, and so iceoryx2's data segments, lives on Linux.
pub const SHM_DIR: &str = "/dev/shm";

/// Bytes free for this user in the filesystem at `dir` (statvfs), `None` where it cannot be read.
pub fn free_bytes(dir: &std::path::Path) -> Option<u64> {
    use std::os::unix::ffi::OsStrExt;
    let c = std::ffi::CString::new(dir.as_os_str().as_bytes()).ok()?;
    let mut st: libc::statvfs = unsafe { std::mem::zeroed() };
    // SAFETY: a NUL-terminated path and a statvfs we own.
    if unsafe { libc::statvfs(c.as_ptr(), &mut st) } != 0 {
        return None;
    }
    Some(st.f_bavail as u64 * st.f_frsize as u64)
}

/// Refuses `needed` bytes of publisher shared memory for `service` when /dev/shm has less free. A segment is
/// created sparse and takes its pages when first written, so a publisher that does not fit would start fine
/// and be killed by SIGBUS at a later publish. (/dev/shm filled by others after the check is not covered.)
pub fn check_shm_space(service: &str, needed: u64) -> Result<(), BridgeError> {
    let dir = std::path::Path::new(SHM_DIR);
    match free_bytes(dir) {
        Some(free) if free < needed => Err(BridgeError::SharedMemory {
            service: service.to_string(),
            dir: SHM_DIR.to_string(),
            needed_mb: needed as f64 / 1048576.0,
            free_mb: free as f64 / 1048576.0,
        }),
        _ => Ok(()),
    }
}

/// Process ids of iceoryx2 nodes on this machine whose process died without cleaning up (a crash, a kill).
/// Their resources are removed by the next node creation or [`Publisher::cleanup_dead_nodes`].
pub fn dead_node_pids() -> Result<Vec<i32>, BridgeError> {
    use iceoryx2::node::NodeView;
    let mut pids = Vec::new();
    Node::<Ipc>::list(Config::global_config(), |state| {
        if let NodeState::Dead(view) = state {
            pids.push(view.details().as_ref().map_or(-1, |d| d.process_id().value()));
        }
        CallbackProgression::Continue
    })
    .map_err(iox("iceoryx2 nodes", "listing the nodes"))?;
    Ok(pids)
}

pub(super) type PubSubFactory<T> =
    iceoryx2::service::port_factory::publish_subscribe::PortFactory<Ipc, [T], FrameHeader>;
pub(super) type EventFactory = iceoryx2::service::port_factory::event::PortFactory<Ipc>;

/// The publish-subscribe service `{prefix}/{topic}` of `T` and its event service.
pub(super) fn open_services<T: BridgePayload>(
    node: &Node<Ipc>,
    cfg: &BridgeConfig,
    topic: &str,
) -> Result<(PubSubFactory<T>, EventFactory), BridgeError> {
    let service_s = cfg.service_name(topic);
    let service = service_s.as_str();
    let name = ServiceName::new(service).map_err(iox(service, "naming the service"))?;
    let pubsub = node
        .service_builder(&name)
        .publish_subscribe::<[T]>()
        .user_header::<FrameHeader>()
        .max_publishers(cfg.max_publishers)
        .max_subscribers(cfg.max_subscribers)
        .subscriber_max_buffer_size(cfg.subscriber_buffer)
        .subscriber_max_borrowed_samples(cfg.subscriber_max_borrowed)
        .history_size(cfg.history)
        .enable_safe_overflow(true)
        .max_nodes(cfg.max_nodes)
        .open_or_create()
        .map_err(iox(
            service,
            "opening or creating the publish-subscribe service (settings must match the other side's BridgeConfig)",
        ))?;
    check_pubsub_settings(service, pubsub.static_config(), cfg)?;
    let ev_name_s = cfg.event_name(topic);
    let ev_name = ServiceName::new(&ev_name_s).map_err(iox(service, "naming the event service"))?;
    let event = node
        .service_builder(&ev_name)
        .event()
        .max_notifiers(cfg.max_publishers)
        .max_listeners(cfg.max_subscribers)
        .max_nodes(cfg.max_nodes)
        .open_or_create()
        .map_err(iox(service, "opening or creating the event service"))?;
    let e = event.static_config();
    let diffs = differences(&[
        ("event max_notifiers", e.max_notifiers(), cfg.max_publishers),
        ("event max_listeners", e.max_listeners(), cfg.max_subscribers),
        ("event max_nodes", e.max_nodes(), cfg.max_nodes),
    ]);
    if !diffs.is_empty() {
        return Err(BridgeError::Foreign { service: ev_name_s, diffs });
    }
    Ok((pubsub, event))
}

/// "name found (expected x), ..." for every setting that differs.
pub(super) fn differences(s: &[(&str, usize, usize)]) -> String {
    let d: Vec<String> =
        s.iter().filter(|(_, a, b)| a != b).map(|(n, found, want)| format!("{n} {found} (expected {want})")).collect();
    d.join(", ")
}

/// iceoryx2 opens an existing service whose limits are at least the requested ones; the bridge needs exactly
/// its own (e.g. a service created with 4 publisher slots would let a second process publish next to the
/// runtime), so anything else is refused.
pub(super) fn check_pubsub_settings(
    service: &str,
    c: &iceoryx2::service::static_config::publish_subscribe::StaticConfig,
    cfg: &BridgeConfig,
) -> Result<(), BridgeError> {
    let mut diffs = differences(&[
        ("max_publishers", c.max_publishers(), cfg.max_publishers),
        ("max_subscribers", c.max_subscribers(), cfg.max_subscribers),
        ("subscriber_buffer", c.subscriber_max_buffer_size(), cfg.subscriber_buffer),
        ("subscriber_max_borrowed", c.subscriber_max_borrowed_samples(), cfg.subscriber_max_borrowed),
        ("history", c.history_size(), cfg.history),
        ("max_nodes", c.max_nodes(), cfg.max_nodes),
    ]);
    if !c.has_safe_overflow() {
        diffs += if diffs.is_empty() { "" } else { ", " };
        diffs += "safe overflow off (expected on)";
    }
    if diffs.is_empty() {
        Ok(())
    } else {
        Err(BridgeError::Foreign { service: service.to_string(), diffs })
    }
}

/// The processes holding a service's publisher ports, for the error that says the slot is taken.
pub(super) fn publisher_holders<T: BridgePayload>(pubsub: &PubSubFactory<T>) -> String {
    let mut pids = Vec::new();
    pubsub.dynamic_config().list_publishers(|p| {
        pids.push(p.node_id.pid::<Ipc>().map(|pid| pid.value()).ok());
        CallbackProgression::Continue
    });
    let me = std::process::id() as i32;
    let names: Vec<String> = pids
        .into_iter()
        .map(|pid| match pid {
            Some(p) if p == me => format!("process {p}, this one"),
            Some(p) => match std::fs::read_to_string(format!("/proc/{p}/comm")) {
                Ok(c) => format!("process {p} `{}`", c.trim()),
                Err(_) => format!("process {p}"),
            },
            None => "a process of unknown id".to_string(),
        })
        .collect();
    if names.is_empty() {
        "held by a port being removed".to_string()
    } else {
        format!("held by {}", names.join(", "))
    }
}
