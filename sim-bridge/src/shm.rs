//! iceoryx2 publish-subscribe services for frames (host → core) and commands (core → host).
//!
//! Two services per bridge instance, named `<instance>/needle.ComplianceFrame.v2` and
//! `<instance>/needle.Command.v2` (the instance defaults to `needle`; tests use a unique one so
//! that parallel runs never meet). Both sides open-or-create them with the same settings
//! ([`frame_service`], [`command_service`]), for a robot of `N` joints (6 or 7): the service
//! names are the same for every joint count, the payload types are not
//! ([`crate::payload::frame_type_name`]), so a host and a controller of different joint counts
//! meet on the same services and the second to open them is refused
//! ([`TransportError::JointCount`], naming both counts) instead of waiting for frames that
//! never come.
//!
//! Zero copy: the host loans an uninitialised frame sample, initialises it in place
//! ([`loan_initialised`]) and writes the frame into it ([`SharedMemoryHost::publish_with`]);
//! the controller steps directly on the received sample and writes its command into a loaned
//! command sample. Nothing of `W` crosses the stack. (`needle serve` builds its frame in the
//! `World`, so it copies the used `m × m` block once into the sample with [`copy_used`]; see
//! [`SharedMemoryHost::publish`].)
//!
//! Stale resources: a process killed without cleaning up leaves its node behind. Every side
//! starts by removing the resources of dead nodes ([`cleanup_dead_nodes`], iceoryx2's node list
//! with `NodeState::Dead`), and the controller does it again whenever it loses its host. A
//! process killed while it was creating a service leaves that service half-created; the next
//! open removes it and creates it again (`open_recovering`).

use crate::payload::{
    CommandHeader, CommandKind, CommandPayload, FrameHeader, FramePayload, copy_used,
    joints_of_type_name,
};
use crate::transport::{ExchangeReport, Transport, TransportError};
use core::time::Duration;
use iceoryx2::node::NodeWaitFailure;
use iceoryx2::port::publisher::Publisher;
use iceoryx2::port::subscriber::Subscriber;
use iceoryx2::prelude::*;
use iceoryx2::sample_mut::SampleMut;
use iceoryx2::service::builder::publish_subscribe::{
    PublishSubscribeCreateError, PublishSubscribeOpenError, PublishSubscribeOpenOrCreateError,
};
use iceoryx2::service::port_factory::publish_subscribe::PortFactory;
use needle_core::payload::Payload;
use needle_core::payload::{COMMAND_TYPE_NAME, Command, ComplianceFrame, FRAME_TYPE_NAME};
use needle_core::zeroed_in_place;
use std::time::Instant;

/// Default deadline on both sides: a controller without a fresh frame, or a host without a
/// command, for this long holds (50 ms).
pub const DEFAULT_DEADLINE: Duration = Duration::from_millis(50);

/// How a side waits for the other while polling.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Wait {
    /// Sleep this long between polls (cheap on a shared machine; adds up to one period of
    /// latency plus the OS timer slack).
    Sleep(Duration),
    /// Yield the CPU between polls (lowest latency, burns a core; benches).
    Spin,
}

impl Default for Wait {
    fn default() -> Self {
        Self::Sleep(Duration::from_micros(50))
    }
}

/// Where and how the two processes meet.
#[derive(Clone, Debug, PartialEq)]
pub struct BridgeConfig {
    /// Service-name prefix shared by the host and its controller (default `needle`).
    pub instance: String,
    /// Deadline after which the waiting side holds (default [`DEFAULT_DEADLINE`]).
    pub deadline: Duration,
    /// How to wait between polls.
    pub wait: Wait,
    /// Install iceoryx2's SIGINT/SIGTERM handler so that Ctrl-C ends the loops cleanly (the
    /// binaries; off in libraries and tests).
    pub handle_signals: bool,
}

impl Default for BridgeConfig {
    fn default() -> Self {
        Self {
            instance: "needle".into(),
            deadline: DEFAULT_DEADLINE,
            wait: Wait::default(),
            handle_signals: false,
        }
    }
}

impl BridgeConfig {
    /// The frame service's name, `<instance>/needle.ComplianceFrame.v2`.
    pub fn frame_service_name(&self) -> String {
        format!("{}/{FRAME_TYPE_NAME}", self.instance)
    }

    /// The command service's name, `<instance>/needle.Command.v2`.
    pub fn command_service_name(&self) -> String {
        format!("{}/{COMMAND_TYPE_NAME}", self.instance)
    }
}

/// The iceoryx2 service flavour used: inter-process, single-threaded ports.
pub type Ipc = ipc::Service;

/// Frame publisher port (`N` joints, 6 by default).
pub type FramePublisher<const M: usize, const N: usize = 6> =
    Publisher<Ipc, FramePayload<M, N>, FrameHeader>;
/// Frame subscriber port.
pub type FrameSubscriber<const M: usize, const N: usize = 6> =
    Subscriber<Ipc, FramePayload<M, N>, FrameHeader>;
/// Command publisher port.
pub type CommandPublisher<const M: usize, const N: usize = 6> =
    Publisher<Ipc, CommandPayload<M, N>, CommandHeader>;
/// Command subscriber port.
pub type CommandSubscriber<const M: usize, const N: usize = 6> =
    Subscriber<Ipc, CommandPayload<M, N>, CommandHeader>;

/// Loans a sample from `publisher`, writes `header` and initialises the payload in place (all
/// zero, current version: [`Payload`]), so that it never transits the stack. The one place
/// where the bridge marks a loaned sample as initialised.
///
/// # Errors
/// [`TransportError::Ipc`] (with `what`) when the loan fails.
pub fn loan_initialised<
    P: Payload + ZeroCopySend + core::fmt::Debug,
    H: ZeroCopySend + core::fmt::Debug + Default,
>(
    publisher: &Publisher<Ipc, P, H>,
    header: H,
    what: &'static str,
) -> Result<SampleMut<Ipc, P, H>, TransportError> {
    let mut sample = publisher
        .loan_uninit()
        .map_err(dbg)
        .map_err(ipc_err(what))?;
    *sample.user_header_mut() = header;
    zeroed_in_place(sample.payload_mut()).stamp();
    // SAFETY: `zeroed_in_place` initialised every byte of the payload (`P: Zeroable`).
    Ok(unsafe { sample.assume_init() })
}

pub(crate) fn ipc_err(what: &'static str) -> impl FnOnce(String) -> TransportError {
    move |detail| TransportError::Ipc { what, detail }
}

fn dbg<E: core::fmt::Debug>(e: E) -> String {
    format!("{e:?}")
}

/// Lowers iceoryx2's log level to errors (it warns on every start that no config file was
/// found, and the defaults are what the bridge wants). Process-wide.
pub fn quiet_logs() {
    set_log_level(LogLevel::Error);
}

/// Creates a node named `name` (visible in `iox2 node list`).
///
/// # Errors
/// [`TransportError::Ipc`] when the name is invalid or the node cannot be created.
pub fn create_node(name: &str, cfg: &BridgeConfig) -> Result<Node<Ipc>, TransportError> {
    let node_name = NodeName::new(name)
        .map_err(dbg)
        .map_err(ipc_err("node name"))?;
    NodeBuilder::new()
        .name(&node_name)
        .signal_handling_mode(if cfg.handle_signals {
            SignalHandlingMode::HandleTerminationRequests
        } else {
            SignalHandlingMode::Disabled
        })
        .create::<Ipc>()
        .map_err(dbg)
        .map_err(ipc_err("create node"))
}

/// Removes the shared-memory resources of every dead node (a process killed without cleaning
/// up) and returns how many were removed.
pub fn cleanup_dead_nodes(node: &Node<Ipc>) -> u64 {
    node.try_cleanup_dead_nodes().cleanups
}

/// Dead nodes listed now (0 when the list cannot be read).
fn dead_nodes() -> u64 {
    let mut n = 0;
    let _ = Node::<Ipc>::list(Config::global_config(), |state| {
        if matches!(state, NodeState::Dead(_)) {
            n += 1;
        }
        CallbackProgression::Continue
    });
    n
}

/// Creates a node and removes the resources of dead nodes; returns the node and how many dead
/// nodes are gone — iceoryx2 already cleans them while it creates a node, so they are counted
/// before and after, not only by the explicit cleanup.
pub(crate) fn create_node_cleaning(
    name: &str,
    cfg: &BridgeConfig,
) -> Result<(Node<Ipc>, u64), TransportError> {
    let before = dead_nodes();
    let node = create_node(name, cfg)?;
    let explicit = cleanup_dead_nodes(&node);
    let gone = before.saturating_sub(dead_nodes());
    Ok((node, explicit.max(gone)))
}

/// Opens or creates the frame service of `cfg` (same settings on both sides: 2 publishers so a
/// restarted host can join before the dead one is cleaned, 2 subscribers, buffer of 2 with
/// overwrite of the oldest — the controller only ever wants the newest frame). Recovers from a
/// service left half-created by a killed process (see [`open_recovering`]).
///
/// # Errors
/// [`TransportError::JointCount`] when the service carries frames of another joint count (the
/// other process runs another robot); [`TransportError::Ipc`], e.g. when the service exists
/// with another incompatible payload (another capacity `M` or layout version).
pub fn frame_service<const M: usize, const N: usize>(
    node: &Node<Ipc>,
    cfg: &BridgeConfig,
) -> Result<PortFactory<Ipc, FramePayload<M, N>, FrameHeader>, TransportError> {
    frame_service_counting(node, cfg, &mut 0)
}

pub(crate) fn frame_service_counting<const M: usize, const N: usize>(
    node: &Node<Ipc>,
    cfg: &BridgeConfig,
    removed: &mut u64,
) -> Result<PortFactory<Ipc, FramePayload<M, N>, FrameHeader>, TransportError> {
    let name = ServiceName::new(&cfg.frame_service_name())
        .map_err(dbg)
        .map_err(ipc_err("frame service name"))?;
    let expected = Expected::of::<FramePayload<M, N>>(N);
    open_recovering(node, &name, "open frame service", expected, removed, || {
        node.service_builder(&name)
            .publish_subscribe::<FramePayload<M, N>>()
            .user_header::<FrameHeader>()
            // One host per instance: a second publisher (a stale host, a forger) is refused.
            .max_publishers(1)
            .max_subscribers(2)
            .history_size(0)
            .subscriber_max_buffer_size(2)
            .subscriber_max_borrowed_samples(2)
            .enable_safe_overflow(true)
            .open_or_create()
    })
}

/// Opens or creates the command service of `cfg` (buffer of 8: hold commands at the
/// controller's rate may queue while a host is busy; it drains them).
///
/// # Errors
/// As [`frame_service`].
pub fn command_service<const M: usize, const N: usize>(
    node: &Node<Ipc>,
    cfg: &BridgeConfig,
) -> Result<PortFactory<Ipc, CommandPayload<M, N>, CommandHeader>, TransportError> {
    command_service_counting(node, cfg, &mut 0)
}

pub(crate) fn command_service_counting<const M: usize, const N: usize>(
    node: &Node<Ipc>,
    cfg: &BridgeConfig,
    removed: &mut u64,
) -> Result<PortFactory<Ipc, CommandPayload<M, N>, CommandHeader>, TransportError> {
    let name = ServiceName::new(&cfg.command_service_name())
        .map_err(dbg)
        .map_err(ipc_err("command service name"))?;
    let expected = Expected::of::<CommandPayload<M, N>>(N);
    open_recovering(
        node,
        &name,
        "open command service",
        expected,
        removed,
        || {
            node.service_builder(&name)
                .publish_subscribe::<CommandPayload<M, N>>()
                .user_header::<CommandHeader>()
                // One controller per instance.
                .max_publishers(1)
                .max_subscribers(2)
                .history_size(0)
                .subscriber_max_buffer_size(8)
                .subscriber_max_borrowed_samples(2)
                .enable_safe_overflow(true)
                .open_or_create()
        },
    )
}

/// The payload a side opens a service with: its iceoryx2 type name, size and joint count.
#[derive(Clone, Copy, Debug)]
struct Expected {
    type_name: &'static str,
    size: usize,
    joints: usize,
}

impl Expected {
    fn of<P: ZeroCopySend>(joints: usize) -> Self {
        Self {
            // SAFETY: only reads the type's name.
            type_name: unsafe { <P as ZeroCopySend>::type_name() },
            size: core::mem::size_of::<P>(),
            joints,
        }
    }
}

/// The error for a service that exists with another payload type than `expected`: the other
/// side's joint count when its payload says one ([`TransportError::JointCount`]), else what it
/// carries (another row capacity or layout version).
fn incompatible(
    node: &Node<Ipc>,
    name: &ServiceName,
    what: &'static str,
    expected: Expected,
    e: &PublishSubscribeOpenOrCreateError,
) -> TransportError {
    let found = match Ipc::details(name, node.config(), MessagingPattern::PublishSubscribe) {
        Ok(Some(d)) => {
            let t = &d
                .static_details
                .publish_subscribe()
                .message_type_details()
                .payload;
            Some((t.type_name().to_string(), t.size()))
        }
        _ => None,
    };
    let Some((type_name, size)) = found else {
        return TransportError::Ipc {
            what,
            detail: format!(
                "{e:?}: the service \"{name}\" exists with another payload than `{}` ({} joints)",
                expected.type_name, expected.joints
            ),
        };
    };
    match joints_of_type_name(&type_name) {
        Some(k) if k != expected.joints => TransportError::JointCount {
            service: name.to_string(),
            found: k,
            expected: expected.joints,
        },
        _ => TransportError::Ipc {
            what,
            detail: format!(
                "{e:?}: the service \"{name}\" carries `{type_name}` of {size} bytes, this side `{}` of {} bytes (another row capacity or layout version: build both sides from the same sources)",
                expected.type_name, expected.size
            ),
        },
    }
}

/// How often a transient open failure (another process cleaning a dead node's share of the
/// same service at this moment) is retried, 10 ms apart.
const TRANSIENT_RETRIES: u32 = 20;

/// Runs `open` (an `open_or_create`) and recovers from the two ways a killed process can leave
/// a service unusable:
///
/// - **Hangs in creation**: the process was killed between writing the service's static config
///   and finalising it. iceoryx2 waits `creation_timeout` (1 s) for the creator and then gives
///   up with `HangsInCreation` — for ever, since nobody will finalise it. A creator that is alive
///   finishes in microseconds, and no process can have opened a service whose static config is
///   not final, so after that wait the service is removed ([`remove_unfinalised_service`]) —
///   once — and created again. Counted in `removed`.
/// - **Transient states** while another process removes a dead node's share of the service at
///   the same moment (`ServiceInCorruptedState`, `IsMarkedForDestruction`, `SystemInFlux`,
///   `DoesNotExist` on open): retried up to [`TRANSIENT_RETRIES`] times.
///
/// A service that exists with another payload type is refused ([`incompatible`]: the joint
/// counts of both sides when they differ).
fn open_recovering<T>(
    node: &Node<Ipc>,
    name: &ServiceName,
    what: &'static str,
    expected: Expected,
    removed: &mut u64,
    mut open: impl FnMut() -> Result<T, PublishSubscribeOpenOrCreateError>,
) -> Result<T, TransportError> {
    use PublishSubscribeCreateError as C;
    use PublishSubscribeOpenError as O;
    use PublishSubscribeOpenOrCreateError as E;
    let mut forced = false;
    let mut retries = 0;
    loop {
        let e = match open() {
            Ok(service) => return Ok(service),
            Err(e) => e,
        };
        let hangs = matches!(
            e,
            E::PublishSubscribeOpenError(O::HangsInCreation)
                | E::PublishSubscribeCreateError(C::HangsInCreation)
        );
        let transient = matches!(
            e,
            E::SystemInFlux
                | E::PublishSubscribeOpenError(
                    O::ServiceInCorruptedState | O::IsMarkedForDestruction | O::DoesNotExist
                )
                | E::PublishSubscribeCreateError(C::IsBeingCreatedByAnotherInstance)
        );
        if hangs && !forced {
            forced = true;
            cleanup_dead_nodes(node);
            match remove_unfinalised_service(node, name) {
                Ok(()) => *removed += 1,
                Err(r) => {
                    return Err(TransportError::Ipc {
                        what,
                        detail: format!(
                            "{e:?}: the service \"{name}\" was left half-created by a killed process and could not be removed: {r}"
                        ),
                    });
                }
            }
        } else if matches!(e, E::PublishSubscribeOpenError(O::IncompatibleTypes)) {
            return Err(incompatible(node, name, what, expected, &e));
        } else if transient && retries < TRANSIENT_RETRIES {
            retries += 1;
            std::thread::sleep(Duration::from_millis(10));
        } else {
            return Err(TransportError::Ipc {
                what,
                detail: format!("{e:?}"),
            });
        }
    }
}

/// Removes what a process killed while creating service `name` left: the service's static
/// config file, still carrying its initial permissions (owner read-write; iceoryx2 makes it
/// read-only once the content is final), and whatever else [`Node::force_remove_service`] finds.
/// iceoryx2 0.10 treats an unfinalised static config as "no service" when removing
/// (`read_static_service_config` returns `None`) but as "hangs in creation" when opening, so
/// no public call removes it; the file is found by the same hash iceoryx2 names it with.
///
/// Call only after an open waited the whole creation timeout on this service.
fn remove_unfinalised_service(node: &Node<Ipc>, name: &ServiceName) -> Result<(), String> {
    use iceoryx2::service::service_hash::ServiceHash;
    use std::os::unix::fs::PermissionsExt;
    // SAFETY: only called when the service's static config stayed unfinalised for the whole
    // creation timeout: its creator is dead (a live one finishes in microseconds) and no process
    // can hold the service open (opening needs the final static config).
    let forced = unsafe { node.force_remove_service(name, MessagingPattern::PublishSubscribe) }
        .map_err(|e| format!("{e:?}"))?;
    let global = &node.config().global;
    let hash = ServiceHash::new::<<Ipc as iceoryx2::service::Service>::ServiceNameHasher>(
        name,
        MessagingPattern::PublishSubscribe,
    );
    let file = std::path::PathBuf::from(format!("{}", global.service_dir())).join(format!(
        "{}{}{}",
        global.prefix,
        hash.as_str(),
        global.service.static_config_storage_suffix
    ));
    match std::fs::metadata(&file) {
        Ok(m) if m.is_file() && m.permissions().mode() & 0o777 == 0o600 => {
            std::fs::remove_file(&file).map_err(|e| format!("{}: {e}", file.display()))
        }
        Ok(_) if forced => Ok(()),
        Ok(m) => Err(format!(
            "{}: not an unfinalised static config (mode {:o})",
            file.display(),
            m.permissions().mode() & 0o777
        )),
        Err(_) if forced => Ok(()),
        Err(e) => Err(format!("{}: {e}", file.display())),
    }
}

/// Counters of the host side.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct HostStats {
    /// Frame samples published (repeats after a timeout included).
    pub frames_published: u64,
    /// Commands accepted (answering the frame waited for).
    pub commands_accepted: u64,
    /// Commands that failed validation (never applied).
    pub commands_rejected: u64,
    /// Commands for another frame or session, and hold commands (ignored).
    pub commands_stale: u64,
    /// Exchanges that ran into the deadline.
    pub timeouts: u64,
    /// Dead nodes whose resources were removed at start.
    pub dead_nodes_cleaned: u64,
    /// Services left half-created by a killed process, removed and created again at start.
    pub hung_services_removed: u64,
}

/// The host's end: publishes frames in place and waits, lock-step, for the command answering
/// each one; a robot of `N` joints (6 by default, or 7).
pub struct SharedMemoryHost<const M: usize, const N: usize = 6> {
    node: Node<Ipc>,
    frames: FramePublisher<M, N>,
    commands: CommandSubscriber<M, N>,
    header: FrameHeader,
    cfg: BridgeConfig,
    stats: HostStats,
}

impl<const M: usize, const N: usize> SharedMemoryHost<M, N> {
    /// Connects a host: cleans the resources of dead nodes, opens both services, creates the
    /// ports, and starts a new session. `setup` is the [`crate::setup_fingerprint`] of the robot
    /// and tuning the controller must use; every frame's header carries it and the joint count
    /// `N`.
    ///
    /// # Errors
    /// [`TransportError::JointCount`] when a controller of another joint count holds the
    /// services; [`TransportError::Ipc`] when a node, service or port cannot be created.
    pub fn connect(cfg: &BridgeConfig, setup: u64) -> Result<Self, TransportError> {
        let (node, dead_nodes_cleaned) = create_node_cleaning("needle-host", cfg)?;
        let mut hung_services_removed = 0;
        let frames = frame_service_counting::<M, N>(&node, cfg, &mut hung_services_removed)?
            .publisher_builder()
            .create()
            .map_err(dbg)
            .map_err(ipc_err("create frame publisher"))?;
        let commands = command_service_counting::<M, N>(&node, cfg, &mut hung_services_removed)?
            .subscriber_builder()
            .create()
            .map_err(dbg)
            .map_err(ipc_err("create command subscriber"))?;
        Ok(Self {
            node,
            frames,
            commands,
            header: FrameHeader {
                session: crate::payload::new_session_id(),
                setup,
                joints: N as u32,
                reserved: 0,
            },
            cfg: cfg.clone(),
            stats: HostStats {
                dead_nodes_cleaned,
                hung_services_removed,
                ..HostStats::default()
            },
        })
    }

    /// This host's session identifier.
    pub fn session(&self) -> u64 {
        self.header.session
    }

    /// The counters so far.
    pub fn stats(&self) -> HostStats {
        self.stats
    }

    /// The configuration.
    pub fn config(&self) -> &BridgeConfig {
        &self.cfg
    }

    /// Publishes one frame written in place: loans a sample, initialises it
    /// ([`loan_initialised`]: all zero, current version) and lets `fill` write the
    /// frame straight into shared memory. Returns the frame's sequence.
    ///
    /// # Errors
    /// [`TransportError::Ipc`] when loaning or sending fails.
    pub fn publish_with(
        &mut self,
        fill: impl FnOnce(&mut ComplianceFrame<M, N>),
    ) -> Result<u64, TransportError> {
        let mut sample = loan_initialised(&self.frames, self.header, "loan frame")?;
        let frame = &mut sample.payload_mut().0;
        fill(frame);
        let sequence = frame.sequence;
        sample.send().map_err(dbg).map_err(ipc_err("send frame"))?;
        self.stats.frames_published += 1;
        Ok(sequence)
    }

    /// Publishes a frame built elsewhere (e.g. in `needle_host`'s `World`), copying its used part
    /// ([`copy_used`]: the `m × m` block of `W`, `m` columns of `C`) into the sample.
    ///
    /// # Errors
    /// As [`Self::publish_with`].
    pub fn publish(&mut self, frame: &ComplianceFrame<M, N>) -> Result<u64, TransportError> {
        self.publish_with(|dst| copy_used(frame, dst))
    }

    /// Waits up to the deadline for the command answering frame `sequence` of this session and
    /// copies it into `cmd`. Everything else received meanwhile is discarded and counted.
    ///
    /// # Errors
    /// [`TransportError::Timeout`] after the deadline; [`TransportError::Ipc`] if receiving
    /// fails or a termination signal arrived (with `handle_signals`).
    pub fn wait_command(
        &mut self,
        sequence: u64,
        cmd: &mut Command<M, N>,
    ) -> Result<ExchangeReport, TransportError> {
        let start = Instant::now();
        let mut report = ExchangeReport::default();
        loop {
            while let Some(sample) = self
                .commands
                .receive()
                .map_err(dbg)
                .map_err(ipc_err("receive command"))?
            {
                let h = *sample.user_header();
                let c = &sample.payload().0;
                if CommandKind::from_raw(h.kind) != Some(CommandKind::Answer)
                    || h.session != self.header.session
                    || c.frame_sequence != sequence
                {
                    self.stats.commands_stale += 1;
                    report.stale_commands += 1;
                    continue;
                }
                if c.validate().is_err() {
                    self.stats.commands_rejected += 1;
                    report.rejected_commands += 1;
                    continue;
                }
                *cmd = *c;
                self.stats.commands_accepted += 1;
                report.round_trip = start.elapsed();
                return Ok(report);
            }
            let waited = start.elapsed();
            if waited >= self.cfg.deadline {
                self.stats.timeouts += 1;
                return Err(TransportError::Timeout { waited });
            }
            pause(&self.node, self.cfg.wait)?;
        }
    }
}

/// One pause between polls; `Err` on a termination request (SIGINT/SIGTERM with
/// `handle_signals`).
pub(crate) fn pause(node: &Node<Ipc>, wait: Wait) -> Result<(), TransportError> {
    match wait {
        // `Interrupt` is any signal that cut the sleep short (SIGCONT after a SIGSTOP, …): only a
        // termination request (SIGTERM, SIGINT) ends the loop.
        Wait::Sleep(d) => match node.wait(d) {
            Ok(()) | Err(NodeWaitFailure::Interrupt) => Ok(()),
            Err(e) => Err(ipc_err("termination requested")(dbg(e))),
        },
        Wait::Spin => {
            std::thread::yield_now();
            Ok(())
        }
    }
}

impl<const M: usize, const N: usize> Transport<M, N> for SharedMemoryHost<M, N> {
    /// Publishes `frame` (one copy of its used part, see [`SharedMemoryHost::publish`]) and waits
    /// for the command answering it.
    fn exchange(
        &mut self,
        frame: &ComplianceFrame<M, N>,
        cmd: &mut Command<M, N>,
    ) -> Result<ExchangeReport, TransportError> {
        let start = Instant::now();
        let sequence = self.publish(frame)?;
        let mut r = self.wait_command(sequence, cmd)?;
        r.round_trip = start.elapsed();
        Ok(r)
    }
}
