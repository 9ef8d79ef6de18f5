//! The async-opcua shell: builds the server (endpoints and users from `[opcua]`), binds it, and
//! runs the updater that copies the latest status snapshot into the address space at most every
//! [`UPDATE_PERIOD`], raising each fault's start and clear as an Alarms & Conditions event
//! (`alarms.rs`). Both run on their own tasks; the cycle only ever publishes on the watch channel.

use std::collections::HashSet;
use std::net::SocketAddr;
use std::sync::Arc;
use std::time::Duration;

use opcua::crypto::SecurityPolicy;
use opcua::server::address_space::{AccessLevel, ObjectBuilder, VariableBuilder};
use opcua::server::node_manager::memory::{SimpleNodeManager, simple_node_manager_imports};
use opcua::server::{
    ANONYMOUS_USER_TOKEN_ID, ServerBuilder, ServerEndpoint, ServerHandle, ServerUserToken,
    SubscriptionCache,
};
use opcua::types::{
    BuildInfo, DataTypeId, DataValue, EUInformation, ExtensionObject, LocalizedText,
    MessageSecurityMode, NodeId, ObjectTypeId, QualifiedName, StatusCode, UAString, VariableTypeId,
    Variant,
};
use tokio::sync::watch;
use tokio::task::JoinHandle;

use super::OpcUaSection;
use super::alarms::{self, Alarms};
use super::instance::{self, Namespaces};
use super::nodesets;
use super::space::{FOLDERS, Point, Quality, Unit, Value, identification, points, unece_unit_id};
use crate::status::ModelIdentity;
use crate::status::StatusSnapshot;

/// Why the OPC UA server could not start. Display is this layer only (the key or step that
/// failed); the cause is its `source()`.
#[derive(Debug, thiserror::Error)]
pub enum OpcUaError {
    /// What `what` names (the listen address, the relay port) could not be set up.
    #[error("{what}")]
    Setup {
        what: String,
        #[source]
        source: retrocomp_model::error::BoxError,
    },
    /// Refused as configured (the message says which key and why).
    #[error("{0}")]
    Refused(String),
    #[error(transparent)]
    Io(#[from] std::io::Error),
}

impl OpcUaError {
    fn setup(what: impl Into<String>, source: impl Into<retrocomp_model::error::BoxError>) -> Self {
        OpcUaError::Setup {
            what: what.into(),
            source: source.into(),
        }
    }
}

/// The box's namespace.
pub(crate) const NAMESPACE_URI: &str = "urn:retrocomp:gateway";
/// Snapshots reach the address space at most this often (10 Hz).
pub(crate) const UPDATE_PERIOD: Duration = Duration::from_millis(100);
/// UNECE units in `EUInformation.namespaceUri` (OPC UA Part 8 §5.6.3).
const UNECE_URI: &str = "http://www.opcfoundation.org/UA/units/un/cefact";

/// A running OPC UA server; [`OpcUaServer::stop`] ends it (dropping it detaches the tasks).
pub struct OpcUaServer {
    /// `opc.tcp://host:port/`, what clients connect to.
    pub endpoint: String,
    pub bound: SocketAddr,
    /// The public listener (relaying to async-opcua's loopback port).
    public: retrocomp_bus::listen::Listening,
    handle: ServerHandle,
    server: JoinHandle<()>,
    updater: JoinHandle<()>,
}

// By hand: async-opcua's server handle has no Debug.
impl std::fmt::Debug for OpcUaServer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OpcUaServer")
            .field("endpoint", &self.endpoint)
            .field("bound", &self.bound)
            .finish_non_exhaustive()
    }
}

impl OpcUaServer {
    /// The public listener's faults (refusals, restarts).
    pub fn health(&self) -> &retrocomp_bus::listen::ListenerHealth {
        &self.public.health
    }

    pub fn stop(self) {
        self.handle.cancel();
        self.updater.abort();
        self.server.abort();
    }
}

/// Bind `[opcua] listen`, build the address space and start serving `status` snapshots.
pub async fn start(
    cfg: &OpcUaSection,
    box_name: &str,
    status: watch::Receiver<Option<Arc<StatusSnapshot>>>,
    model: Option<ModelIdentity>,
) -> Result<OpcUaServer, OpcUaError> {
    let listen = cfg.listen_addr();
    // async-opcua owns its accept loop (no cap; an accept error is logged and retried at once, so
    // EMFILE spins). It listens on a private loopback port instead, and the public address is a
    // listener on the box's policy (`retrocomp_bus::listen`) that relays each admitted connection there.
    let inner = tokio::net::TcpListener::bind((std::net::Ipv4Addr::LOCALHOST, 0))
        .await
        .map_err(|e| OpcUaError::setup("opcua: binding its loopback relay port".to_string(), e))?;
    let inner_addr = inner.local_addr()?;
    let public = retrocomp_bus::listen::listen(listen, relay_spec(cfg, inner_addr))
        .await
        .map_err(|e| OpcUaError::setup(format!("opcua.listen: binding {listen}"), e))?;
    let bound = public.addr;
    let host = cfg.host.clone().unwrap_or_else(|| bound.ip().to_string());
    let b = builder(cfg, box_name, &host, bound.port())?;
    let built = if cfg.has_users() {
        b.build()
    } else {
        super::pki::build_without_store(b)
    };
    let (server, handle) = built.map_err(|e| OpcUaError::Refused(format!("opcua: {e}")))?;
    let server = tokio::spawn(async move {
        if let Err(e) = server.run_with(inner).await {
            tracing::error!(%e, "the OPC UA server stopped");
        }
    });
    advertise_public_port(&handle, inner_addr.port(), bound.port()).await;
    let nm = handle
        .node_managers()
        .get_of_type::<SimpleNodeManager>()
        .ok_or_else(|| {
            OpcUaError::Refused("opcua: no node manager for the box's namespace".into())
        })?;
    let index = |uri: &str| {
        handle
            .get_namespace_index(uri)
            .ok_or_else(|| OpcUaError::Refused(format!("opcua: namespace {uri} not registered")))
    };
    let ns = Namespaces {
        own: index(NAMESPACE_URI)?,
        di: index(nodesets::DI_URI)?,
        machinery: index(nodesets::MACHINERY_URI)?,
        machine_tool: index(nodesets::MACHINE_TOOL_URI)?,
    };
    let ident = cfg.identification.clone().unwrap_or_default();
    let mut space = Space::new(nm, ns, box_name, &ident);
    space.update(
        &identification(box_name, model.as_ref()),
        None,
        handle.subscriptions(),
    );
    let subs = handle.subscriptions().clone();
    let updater = tokio::spawn(update_loop(
        space,
        status,
        model,
        box_name.to_string(),
        subs,
    ));
    let endpoint = format!("opc.tcp://{host}:{}/", bound.port());
    Ok(OpcUaServer {
        endpoint,
        bound,
        public,
        handle,
        server,
        updater,
    })
}

/// The public listener: each admitted connection is relayed byte for byte to `inner`.
fn relay_spec(cfg: &OpcUaSection, inner: SocketAddr) -> retrocomp_bus::listen::Spec {
    retrocomp_bus::listen::Spec {
        name: "opcua",
        policy: cfg.listen_policy.clone(),
        refusal: b"",
        handler: Arc::new(move |mut conn: retrocomp_bus::listen::Conn| {
            Box::pin(async move {
                let Ok(mut up) = tokio::net::TcpStream::connect(inner).await else {
                    tracing::debug!(peer = %conn.peer, "opcua relay: loopback port refused");
                    return;
                };
                let _ = up.set_nodelay(true);
                let _ = conn.stream.get_ref().set_nodelay(true);
                let _ = tokio::io::copy_bidirectional(&mut conn.stream, &mut up).await;
            })
        }),
    }
}

/// async-opcua builds endpoint URLs from the port it listens on (the loopback relay port): once
/// `run_with` has recorded that port, put the public one in its place. Bounded: 5 s.
async fn advertise_public_port(handle: &ServerHandle, inner: u16, public: u16) {
    use std::sync::atomic::Ordering;
    let port = &handle.info().port;
    for _ in 0..500 {
        if port.load(Ordering::Relaxed) == inner {
            port.store(public, Ordering::Relaxed);
            return;
        }
        tokio::time::sleep(Duration::from_millis(10)).await;
    }
    tracing::warn!(
        inner,
        public,
        "opcua: the server never recorded its port; endpoint URLs may name the relay port"
    );
}

fn builder(
    cfg: &OpcUaSection,
    box_name: &str,
    host: &str,
    port: u16,
) -> Result<ServerBuilder, OpcUaError> {
    let mut b = ServerBuilder::new()
        .application_name(format!("retrocomp {box_name}"))
        .application_uri(format!("urn:retrocomp:{box_name}"))
        .product_uri("urn:retrocomp")
        .host(host)
        .port(port)
        .create_sample_keypair(cfg.has_users())
        .build_info(build_info())
        .trust_client_certs(cfg.trust_client_certs)
        .discovery_urls(vec!["/".to_owned()])
        .max_sessions(16)
        .with_node_manager(simple_node_manager_imports(
            nodesets::imports(NAMESPACE_URI).map_err(OpcUaError::Refused)?,
            "retrocomp",
        ));
    // Anonymous only: `pki::build_without_store` gives it a folder for the build alone.
    if let Some(pki) = &cfg.pki_dir {
        b = b.pki_dir(pki);
    }
    if cfg.anonymous() {
        let ids = [ANONYMOUS_USER_TOKEN_ID.to_string()];
        b = b.add_endpoint("none", ServerEndpoint::new_none("/", &ids));
    }
    if cfg.has_users() {
        let mut ids = Vec::new();
        for u in &cfg.users {
            let pw = super::read_password(&u.password_file).map_err(OpcUaError::Refused)?;
            b = b.add_user_token(&u.name, ServerUserToken::user_pass(u.name.as_str(), &pw));
            ids.push(u.name.clone());
        }
        // The server matches the token's certificate by thumbprint and checks its signature over
        // the server's certificate and nonce (async-opcua's X509IdentityToken handling).
        for u in &cfg.cert_users {
            b = b.add_user_token(
                &u.name,
                ServerUserToken::x509(u.name.as_str(), &u.certificate),
            );
            ids.push(u.name.clone());
        }
        if cfg.anonymous() {
            ids.push(ANONYMOUS_USER_TOKEN_ID.to_string());
        }
        b = b.add_endpoint(
            "basic256sha256_sign_encrypt",
            ServerEndpoint::new(
                "/",
                SecurityPolicy::Basic256Sha256,
                MessageSecurityMode::SignAndEncrypt,
                &ids,
            ),
        );
    }
    Ok(b)
}

/// `model`: the identity at start; a snapshot's own (after `POST /api/model`) replaces it, and
/// the `Identification` variables follow.
async fn update_loop(
    mut space: Space,
    mut status: watch::Receiver<Option<Arc<StatusSnapshot>>>,
    mut model: Option<ModelIdentity>,
    box_name: String,
    subs: Arc<SubscriptionCache>,
) {
    let mut tick = tokio::time::interval(UPDATE_PERIOD);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    let mut alarms = Alarms::default();
    let machine = NodeId::new(space.ns, space.root.clone());
    // EventIds are the run's start (Unix ns) and a sequence number: unique across restarts.
    #[expect(
        clippy::cast_possible_truncation,
        clippy::cast_sign_loss,
        reason = "Unix ns of any wall time after 1970 fit a u64 (until 2554)"
    )]
    let run = (crate::northbound::history::unix_now_s() * 1e9) as u64;
    loop {
        tick.tick().await;
        // Wait for a snapshot newer than the last one shown; the Arc is cloned out so the
        // channel's lock is held for no longer than that.
        if status.changed().await.is_err() {
            return;
        }
        let Some(snap) = status.borrow_and_update().clone() else {
            continue;
        };
        if snap.model.is_some() && snap.model != model {
            model.clone_from(&snap.model);
            space.update(&identification(&box_name, model.as_ref()), None, &subs);
        }
        space.update(&points(&snap, model.as_ref()), Some(snap.t_s), &subs);
        raise_alarms(&alarms.observe(&snap), snap.t_s, &machine, run, &subs);
    }
}

/// Each transition's event to the clients subscribed to the machine's or the server's events.
/// `snap_t_s`: the observed snapshot's time on the gateway clock (a start is placed at its
/// `since`, that long before now).
fn raise_alarms(
    transitions: &[alarms::Transition],
    snap_t_s: f64,
    machine: &NodeId,
    run: u64,
    subs: &SubscriptionCache,
) {
    if transitions.is_empty() {
        return;
    }
    let now_unix_s = crate::northbound::history::unix_now_s();
    let now = unix_time(now_unix_s);
    let events: Vec<_> = transitions
        .iter()
        .map(|t| {
            let time = unix_time(now_unix_s - (snap_t_s - t.t_s).max(0.0));
            alarms::event(t, machine, time, now, run)
        })
        .collect();
    let events = events.iter().map(|e| {
        let e: &dyn opcua::nodes::Event = e;
        (e, machine)
    });
    subs.notify_events(events);
}

/// The box's nodes in the simple node manager: objects along each path created on first sight.
struct Space {
    nm: Arc<SimpleNodeManager>,
    ns: u16,
    root: String,
    known: HashSet<String>,
    failing: bool,
}

impl Space {
    fn new(
        nm: Arc<SimpleNodeManager>,
        ns: Namespaces,
        box_name: &str,
        ident: &super::Identification,
    ) -> Self {
        let root = format!("Machines/{box_name}");
        instance::insert(&mut nm.address_space().write(), ns, &root, box_name, ident);
        Space {
            nm,
            ns: ns.own,
            root,
            known: HashSet::new(),
            failing: false,
        }
    }

    fn id(&self, path: &str) -> NodeId {
        NodeId::new(self.ns, format!("{}/{path}", self.root))
    }

    /// `snap_t_s`: the snapshot's time on the gateway clock (None for what has no snapshot): a
    /// point's reading time is placed that long before now.
    fn update(&mut self, pts: &[Point], snap_t_s: Option<f64>, subs: &SubscriptionCache) {
        for p in pts {
            if !self.known.contains(&p.path) {
                self.create(p);
                self.known.insert(p.path.clone());
            }
        }
        let now_unix_s = crate::northbound::history::unix_now_s();
        let now = unix_time(now_unix_s);
        let ids: Vec<NodeId> = pts.iter().map(|p| self.id(&p.path)).collect();
        let values = ids.iter().zip(pts).map(|(id, p)| {
            let source = match (p.source_t_s, snap_t_s) {
                (Some(read_s), Some(snap_s)) => unix_time(now_unix_s - (snap_s - read_s).max(0.0)),
                _ => now,
            };
            (id, None, data_value(&p.value, p.quality, source, now))
        });
        // Logged once when it starts failing and once when it works again.
        let result = self.nm.set_values(subs, values);
        match (&result, self.failing) {
            (Err(e), false) => tracing::error!(%e, "opcua: cannot set values"),
            (Ok(()), true) => tracing::info!("opcua: values set again"),
            _ => {}
        }
        self.failing = result.is_err();
    }

    /// The variable at `p.path` and every object above it that does not exist yet.
    fn create(&self, p: &Point) {
        let mut s = self.nm.address_space().write();
        let parts: Vec<&str> = p.path.split('/').collect();
        let (name, objects) = parts.split_last().expect("split yields at least one part");
        let mut parent = NodeId::new(self.ns, self.root.clone());
        for (i, &name) in objects.iter().enumerate() {
            let id = self.id(&objects[..=i].join("/"));
            if !s.node_exists(&id) {
                let b = ObjectBuilder::new(&id, QualifiedName::new(self.ns, name), name)
                    .component_of(parent.clone());
                let b = if FOLDERS.contains(&name) {
                    b.has_type_definition(ObjectTypeId::FolderType)
                } else {
                    b.has_type_definition(ObjectTypeId::BaseObjectType)
                };
                b.insert(&mut *s);
            }
            parent = id;
        }
        let name = *name;
        let id = self.id(&p.path);
        let (data_type, rank) = match &p.value {
            Value::F64(_) => (DataTypeId::Double, -1),
            Value::Bool(_) => (DataTypeId::Boolean, -1),
            Value::U64(_) => (DataTypeId::UInt64, -1),
            Value::Str(_) => (DataTypeId::String, -1),
            Value::StrArray(_) => (DataTypeId::String, 1),
        };
        let var_type = if p.unit.is_some() {
            VariableTypeId::AnalogUnitType
        } else {
            VariableTypeId::BaseDataVariableType
        };
        let read = AccessLevel::CURRENT_READ;
        VariableBuilder::new(&id, QualifiedName::new(self.ns, name), name)
            .data_type(data_type)
            .value_rank(rank)
            .access_level(read)
            .user_access_level(read)
            .minimum_sampling_interval(UPDATE_PERIOD.as_secs_f64() * 1e3)
            .has_type_definition(var_type)
            .component_of(parent)
            .insert(&mut *s);
        if let Some(unit) = p.unit {
            let eu_id = NodeId::new(
                self.ns,
                format!("{}/{}/EngineeringUnits", self.root, p.path),
            );
            VariableBuilder::new(
                &eu_id,
                QualifiedName::new(0, "EngineeringUnits"),
                "EngineeringUnits",
            )
            .data_type(DataTypeId::EUInformation)
            .value(Variant::from(ExtensionObject::from_message(
                eu_information(unit),
            )))
            .access_level(read)
            .user_access_level(read)
            .has_type_definition(VariableTypeId::PropertyType)
            .property_of(id)
            .insert(&mut *s);
        }
    }
}

/// `Server/ServerStatus/BuildInfo`: this build of retrocomp. The build date is when the gateway
/// crate was compiled (`build.rs`; `SOURCE_DATE_EPOCH` for reproducible builds).
fn build_info() -> BuildInfo {
    let unix_s: i64 = env!("RETROCOMP_BUILD_UNIX_S").parse().unwrap_or(0);
    BuildInfo {
        product_uri: "urn:retrocomp".into(),
        manufacturer_name: "retrocomp project".into(),
        product_name: "retrocomp gateway".into(),
        software_version: env!("CARGO_PKG_VERSION").into(),
        build_number: env!("CARGO_PKG_VERSION").into(),
        build_date: unix_time(unix_s as f64),
    }
}

/// OPC UA DateTime (100 ns ticks since 1601-01-01) of a Unix time in seconds.
#[expect(
    clippy::cast_possible_truncation,
    reason = "ticks of any wall time since 1601 fit an i64 (it overflows in 30828)"
)]
fn unix_time(unix_s: f64) -> opcua::types::DateTime {
    const UNIX_EPOCH_TICKS: i64 = 11_644_473_600 * 10_000_000;
    opcua::types::DateTime::from(UNIX_EPOCH_TICKS + (unix_s * 1e7).round() as i64)
}

fn eu_information(u: Unit) -> EUInformation {
    EUInformation {
        namespace_uri: UAString::from(UNECE_URI),
        unit_id: unece_unit_id(u.code),
        display_name: LocalizedText::new("en", u.symbol),
        description: LocalizedText::new("en", u.name),
    }
}

/// `source`: when the value was read (SourceTimestamp); `now`: when the server took it
/// (ServerTimestamp). The StatusCode follows the point's quality.
fn data_value(
    v: &Value,
    quality: Quality,
    source: opcua::types::DateTime,
    now: opcua::types::DateTime,
) -> DataValue {
    let variant = match v {
        // No value (e.g. no target while inputs are stale): NaN under a Bad status, so no client
        // takes it for a number.
        Value::F64(x) => Variant::Double(x.unwrap_or(f64::NAN)),
        Value::Bool(b) => Variant::Boolean(*b),
        Value::U64(n) => Variant::UInt64(*n),
        Value::Str(s) => Variant::String(s.as_str().into()),
        Value::StrArray(a) => Variant::from(
            a.iter()
                .map(|s| UAString::from(s.as_str()))
                .collect::<Vec<_>>(),
        ),
    };
    let status = match quality {
        Quality::Good => StatusCode::Good,
        Quality::LastUsable => StatusCode::UncertainLastUsableValue,
        Quality::Substituted => StatusCode::UncertainSubstituteValue,
        Quality::NoData => StatusCode::BadNoData,
        Quality::OutOfRange => StatusCode::BadOutOfRange,
        Quality::DeviceFailure => StatusCode::BadDeviceFailure,
    };
    DataValue {
        value: Some(variant),
        status: Some(status),
        // No picoseconds: asyncua 2.1 turns a present ServerPicoseconds into a ServerTimestamp
        // of 1601-01-01 (or 9999-12-31 on a Read).
        source_timestamp: Some(source),
        source_picoseconds: None,
        server_timestamp: Some(now),
        server_picoseconds: None,
    }
}
