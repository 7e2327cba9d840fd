//! Client proxies for the station's D-Bus API (used by `scanstation status|jobs|submit|cancel|watch|rig`).
// zbus's proxy macro generates proxy types and signal streams without docs; the methods are the API's, as
// README's D-Bus section documents them.
#![allow(missing_docs)]

use std::collections::HashMap;

use zbus::proxy;
use zbus::zvariant::{OwnedObjectPath, OwnedValue, Value};

#[proxy(
    interface = "org.scanstation.Station1.Manager",
    default_service = "org.scanstation.Station1",
    default_path = "/org/scanstation/Station1",
    gen_blocking = false
)]
pub trait Manager {
    fn submit_file(&self, path: &str, options: HashMap<&str, Value<'_>>) -> zbus::Result<OwnedObjectPath>;
    fn start_scan(&self, options: HashMap<&str, Value<'_>>) -> zbus::Result<OwnedObjectPath>;
    fn get_history(&self, since_usec: u64, limit: u32) -> zbus::Result<Vec<HashMap<String, OwnedValue>>>;
    fn pause_intake(&self) -> zbus::Result<()>;
    fn resume_intake(&self) -> zbus::Result<()>;
    #[zbus(property)]
    fn version(&self) -> zbus::Result<String>;
    #[zbus(property)]
    fn state(&self) -> zbus::Result<String>;
    #[zbus(property)]
    fn active_jobs(&self) -> zbus::Result<Vec<OwnedObjectPath>>;
    #[zbus(property)]
    fn queued_jobs(&self) -> zbus::Result<Vec<OwnedObjectPath>>;
    #[zbus(property)]
    fn jobs_succeeded(&self) -> zbus::Result<u64>;
    #[zbus(property)]
    fn jobs_failed(&self) -> zbus::Result<u64>;
    #[zbus(property)]
    fn memory_budget(&self) -> zbus::Result<u64>;
    #[zbus(signal)]
    fn job_finished(&self, job: OwnedObjectPath, result: String, error_code: String) -> zbus::Result<()>;
}

#[proxy(interface = "org.scanstation.Station1.Job", default_service = "org.scanstation.Station1", gen_blocking = false)]
pub trait Job {
    fn cancel(&self) -> zbus::Result<()>;
    #[zbus(name = "Continue")]
    fn proceed(&self) -> zbus::Result<()>;
    #[zbus(signal)]
    fn completed(&self, result: String, error_code: String, message: String) -> zbus::Result<()>;
}

/// What the CLI client does, over D-Bus; every function returns JSON for `--json` and text output.
pub mod ops {
    use std::collections::HashMap;

    use futures_util::StreamExt;
    use zbus::Connection;
    use zbus::zvariant::{OwnedValue, Value};

    use super::{JobProxy, ManagerProxy};
    use crate::daemon::config::{JobOptions, option_keys};
    use crate::daemon::dbus::{BUS_NAME, JOB_IFACE, MANAGER_PATH};
    use crate::error::{Error, ErrorCode, Result};

    /// A device's code from an `org.scanstation.Station1.Error.Device` message (`[device.timeout] …`).
    fn device_code(msg: &str) -> Option<ErrorCode> {
        let code = msg.strip_prefix('[')?.split(']').next()?;
        [
            ErrorCode::DeviceUnplugged,
            ErrorCode::DeviceWrongFirmware,
            ErrorCode::DeviceTimeout,
            ErrorCode::DeviceAlarm,
            ErrorCode::DeviceRefused,
            ErrorCode::DevicePosition,
            ErrorCode::DeviceConfig,
            ErrorCode::DeviceBusOff,
            ErrorCode::DeviceLost,
            ErrorCode::DeviceEmergency,
            ErrorCode::DeviceEmptyView,
        ]
        .into_iter()
        .find(|c| c.as_str() == code)
    }

    fn bus_err(e: zbus::Error) -> Error {
        match &e {
            zbus::Error::MethodError(name, msg, _) if name.as_str() == "org.scanstation.Station1.Error.Device" => {
                let msg = msg.as_deref().unwrap_or("");
                let code = device_code(msg).unwrap_or(ErrorCode::DaemonRefused);
                let text = msg.split_once("] ").map_or(msg, |(_, t)| t);
                Error::new(code, text.to_string())
            }
            zbus::Error::MethodError(name, msg, _) => {
                let unavailable = name.as_str() == "org.freedesktop.DBus.Error.ServiceUnknown"
                    || name.as_str() == "org.freedesktop.DBus.Error.NameHasNoOwner";
                Error::new(
                    if unavailable { ErrorCode::DaemonUnavailable } else { ErrorCode::DaemonRefused },
                    format!("{name}: {}", msg.as_deref().unwrap_or("")),
                )
            }
            _ => Error::new(ErrorCode::DaemonUnavailable, e.to_string())
                .with_hint("is scanstationd running, and on this bus (--session)?"),
        }
    }

    /// Connect to the system bus, or the session bus.
    ///
    /// # Errors
    /// `daemon.unavailable`.
    pub async fn connect(session: bool) -> Result<Connection> {
        let c = if session { Connection::session().await } else { Connection::system().await };
        c.map_err(bus_err)
    }

    fn to_json(v: &Value<'_>) -> serde_json::Value {
        use serde_json::json;
        match v {
            Value::U8(x) => json!(x),
            Value::Bool(x) => json!(x),
            Value::I16(x) => json!(x),
            Value::U16(x) => json!(x),
            Value::I32(x) => json!(x),
            Value::U32(x) => json!(x),
            Value::I64(x) => json!(x),
            Value::U64(x) => json!(x),
            Value::F64(x) => json!(x),
            Value::Str(s) => json!(s.as_str()),
            Value::ObjectPath(p) => json!(p.as_str()),
            Value::Value(b) => to_json(b),
            Value::Array(a) => serde_json::Value::Array(a.iter().map(to_json).collect()),
            Value::Dict(d) => {
                let mut m = serde_json::Map::new();
                for (k, v) in d.iter() {
                    let key = match to_json(k) {
                        serde_json::Value::String(s) => s,
                        o => o.to_string(),
                    };
                    m.insert(key, to_json(v));
                }
                serde_json::Value::Object(m)
            }
            o => json!(o.to_string()),
        }
    }

    fn props_json(p: &HashMap<String, OwnedValue>) -> serde_json::Value {
        let mut m = serde_json::Map::new();
        let mut keys: Vec<_> = p.keys().collect();
        keys.sort();
        for k in keys {
            m.insert(k.clone(), to_json(&p[k]));
        }
        serde_json::Value::Object(m)
    }

    /// The Manager's properties.
    ///
    /// # Errors
    /// `daemon.*`.
    pub async fn status(conn: &Connection) -> Result<serde_json::Value> {
        all_properties(conn, MANAGER_PATH.to_string(), crate::daemon::dbus::MANAGER_IFACE).await
    }

    /// `GetAll` of one interface of one station object, as JSON.
    async fn all_properties(conn: &Connection, path: String, iface: &'static str) -> Result<serde_json::Value> {
        let props = zbus::fdo::PropertiesProxy::builder(conn)
            .destination(BUS_NAME)
            .map_err(bus_err)?
            .path(path)
            .map_err(bus_err)?
            .build()
            .await
            .map_err(bus_err)?;
        props
            .get_all(zbus::names::InterfaceName::from_static_str_unchecked(iface))
            .await
            .map(|a| props_json(&a))
            .map_err(|e| bus_err(e.into()))
    }

    /// Every job object (queued, running, and finished ones still lingering), oldest first.
    ///
    /// # Errors
    /// `daemon.*`.
    pub async fn jobs(conn: &Connection) -> Result<Vec<serde_json::Value>> {
        let om = zbus::fdo::ObjectManagerProxy::builder(conn)
            .destination(BUS_NAME)
            .map_err(bus_err)?
            .path(MANAGER_PATH)
            .map_err(bus_err)?
            .build()
            .await
            .map_err(bus_err)?;
        let objects = om.get_managed_objects().await.map_err(|e| bus_err(e.into()))?;
        let mut out: Vec<(String, serde_json::Value)> = objects
            .iter()
            .filter_map(|(path, ifaces)| {
                ifaces.iter().find(|(n, _)| n.as_str() == JOB_IFACE).map(|(_, p)| {
                    let mut j = props_json(p);
                    j["Path"] = serde_json::json!(path.as_str());
                    (path.to_string(), j)
                })
            })
            .collect();
        out.sort_by(|a, b| a.0.cmp(&b.0));
        Ok(out.into_iter().map(|(_, j)| j).collect())
    }

    /// Submit a file (its absolute path) with options; the job's object path.
    ///
    /// # Errors
    /// `daemon.*`; `input.not-found` when the path cannot be made absolute.
    pub async fn submit(conn: &Connection, file: &std::path::Path, job: &JobOptions) -> Result<String> {
        let abs = std::fs::canonicalize(file)
            .map_err(|e| Error::new(ErrorCode::InputNotFound, format!("{}: {e}", file.display())))?;
        let mgr = ManagerProxy::new(conn).await.map_err(bus_err)?;
        let mut opts: HashMap<&str, Value<'_>> = HashMap::new();
        job_options(job, &mut opts);
        let p = mgr.submit_file(&abs.to_string_lossy(), opts).await.map_err(bus_err)?;
        Ok(p.to_string())
    }

    /// A job's options as `SubmitFile` and `StartScan` take them ([`option_keys::JOB`]): only those given.
    fn job_options(o: &JobOptions, opts: &mut HashMap<&str, Value<'_>>) {
        if let Some(v) = o.vertices {
            opts.insert(option_keys::VERTICES, Value::U32(u32::try_from(v).unwrap_or(u32::MAX)));
        }
        if let Some(t) = o.tolerance {
            opts.insert(option_keys::TOLERANCE, Value::F64(t));
        }
        if let Some(s) = o.seed {
            opts.insert(option_keys::SEED, Value::U64(s));
        }
        if let Some(a) = o.accept_degraded {
            opts.insert(option_keys::ACCEPT_DEGRADED, Value::Bool(a));
        }
    }

    /// Start a scan session; the job's object path.
    ///
    /// # Errors
    /// `daemon.*`, `device.*` (no rig), `input.bad-argument`.
    pub async fn scan(conn: &Connection, o: &ScanOptions) -> Result<String> {
        let mgr = ManagerProxy::new(conn).await.map_err(bus_err)?;
        let mut opts: HashMap<&str, Value<'_>> = HashMap::new();
        if let Some(v) = o.views {
            opts.insert(option_keys::VIEWS, Value::U32(v));
        }
        if let Some(s) = o.step_deg {
            opts.insert(option_keys::STEP_DEG, Value::F64(s));
        }
        if let Some(t) = &o.tilts {
            opts.insert(option_keys::TILTS, Value::from(t.as_str()));
        }
        if let Some(c) = o.coverage {
            opts.insert(option_keys::COVERAGE, Value::F64(c));
        }
        if let Some(n) = o.max_views {
            opts.insert(option_keys::MAX_VIEWS, Value::U32(n));
        }
        if let Some(n) = o.passes {
            opts.insert(option_keys::PASSES, Value::U32(n));
        }
        if let Some(n) = &o.name {
            opts.insert(option_keys::NAME, Value::from(n.as_str()));
        }
        if let Some(f) = &o.fea {
            let abs = std::fs::canonicalize(f)
                .map_err(|e| Error::new(ErrorCode::InputNotFound, format!("{}: {e}", f.display())))?;
            opts.insert(option_keys::FEA, Value::from(abs.to_string_lossy().into_owned()));
        }
        job_options(&o.job, &mut opts);
        let p = mgr.start_scan(opts).await.map_err(bus_err)?;
        Ok(p.to_string())
    }

    /// What `scanstation scan` asks for.
    #[derive(Clone, Debug, Default)]
    pub struct ScanOptions {
        /// Views.
        pub views: Option<u32>,
        /// Degrees between views.
        pub step_deg: Option<f64>,
        /// A tilting table's rings (`TILT:VIEWS,…`).
        pub tilts: Option<String>,
        /// Choose views where the surface is unseen until this share is seen.
        pub coverage: Option<f64>,
        /// The most views, chosen ones included.
        pub max_views: Option<u32>,
        /// Passes, the object turned over between two.
        pub passes: Option<u32>,
        /// The scan's name.
        pub name: Option<String>,
        /// An FEA spec (made absolute here).
        pub fea: Option<std::path::PathBuf>,
        /// The conversion's options.
        pub job: JobOptions,
    }

    /// The rig's devices: each configured one's properties (`null` when not configured).
    ///
    /// # Errors
    /// `daemon.*`.
    pub async fn rig_status(conn: &Connection) -> Result<serde_json::Value> {
        use crate::daemon::rig::{TRIGGER_PATH, TURNTABLE_PATH};
        let mut out = serde_json::Map::new();
        for (name, path, iface) in [
            ("turntable", TURNTABLE_PATH, "org.scanstation.Station1.Turntable"),
            ("trigger", TRIGGER_PATH, "org.scanstation.Station1.Trigger"),
        ] {
            let v = match all_properties(conn, path.to_string(), iface).await {
                Ok(v) => v,
                // Not configured: the object (or its interface) is not exported.
                Err(e) if e.message.contains("UnknownObject") || e.message.contains("UnknownInterface") => {
                    serde_json::Value::Null
                }
                Err(e) => return Err(e),
            };
            out.insert(name.into(), v);
        }
        Ok(serde_json::Value::Object(out))
    }

    async fn rig_call<R>(
        conn: &Connection,
        path: &str,
        iface: &str,
        method: &str,
        body: &(impl serde::Serialize + zbus::zvariant::DynamicType),
    ) -> Result<R>
    where
        R: for<'d> zbus::zvariant::DynamicDeserialize<'d>,
    {
        let reply = conn.call_method(Some(BUS_NAME), path, Some(iface), method, body).await.map_err(bus_err)?;
        reply.body().deserialize::<R>().map_err(bus_err)
    }

    /// Home the turntable.
    ///
    /// # Errors
    /// `daemon.*`, `device.*`.
    pub async fn rig_home(conn: &Connection) -> Result<()> {
        rig_call::<()>(conn, crate::daemon::rig::TURNTABLE_PATH, "org.scanstation.Station1.Turntable", "Home", &())
            .await
    }

    /// Turn the table to `degrees` (and a tilting table's cradle to `tilt`); the angle reached.
    ///
    /// # Errors
    /// `daemon.*`, `device.*`.
    pub async fn rig_move(conn: &Connection, degrees: f64, tilt: Option<f64>) -> Result<f64> {
        let mut opts: HashMap<&str, Value<'_>> = HashMap::new();
        if let Some(t) = tilt {
            opts.insert("tilt", Value::F64(t));
        }
        rig_call(
            conn,
            crate::daemon::rig::TURNTABLE_PATH,
            "org.scanstation.Station1.Turntable",
            "MoveTo",
            &(degrees, opts),
        )
        .await
    }

    /// Fire the scanner's `channel` and wait for the view; when the trigger was sent, µs since the epoch.
    ///
    /// # Errors
    /// `daemon.*`, `device.*`.
    pub async fn rig_fire(conn: &Connection, channel: u32) -> Result<u64> {
        let opts: HashMap<&str, Value<'_>> = HashMap::new();
        rig_call(conn, crate::daemon::rig::TRIGGER_PATH, "org.scanstation.Station1.Trigger", "Fire", &(channel, opts))
            .await
    }

    /// A job's object path from an id or a path.
    pub fn job_path(id_or_path: &str) -> String {
        if id_or_path.starts_with('/') { id_or_path.to_string() } else { format!("{MANAGER_PATH}/jobs/{id_or_path}") }
    }

    /// Cancel a job.
    ///
    /// # Errors
    /// `daemon.*` (`org.scanstation.Station1.Error.NotCancelable` once finished).
    pub async fn cancel(conn: &Connection, id: &str) -> Result<()> {
        let job = JobProxy::builder(conn).path(job_path(id)).map_err(bus_err)?.build().await.map_err(bus_err)?;
        job.cancel().await.map_err(bus_err)
    }

    /// Tell a scan waiting for a person (the object turned over between two passes) that it is done.
    ///
    /// # Errors
    /// `daemon.*` (`org.scanstation.Station1.Error.NotWaiting` when the job is not waiting).
    pub async fn proceed(conn: &Connection, id: &str) -> Result<()> {
        let job = JobProxy::builder(conn).path(job_path(id)).map_err(bus_err)?.build().await.map_err(bus_err)?;
        job.proceed().await.map_err(bus_err)
    }

    /// Follow signals of the station (one job when `id` is given, until its `Completed`; all jobs
    /// otherwise, until interrupted), handing each event to `on_event` as JSON (`event`: `finished` when
    /// the job had already ended, `changed` with the changed `properties`, `completed`, `job-finished`; with
    /// the job's `path`). Returns the job's final properties (one job) or null.
    ///
    /// # Errors
    /// `daemon.*`.
    pub async fn watch(
        conn: &Connection,
        id: Option<&str>,
        on_event: &mut (dyn FnMut(&serde_json::Value) + Send),
    ) -> Result<serde_json::Value> {
        let path = id.map(job_path);
        let mut rule =
            zbus::MatchRule::builder().msg_type(zbus::message::Type::Signal).sender(BUS_NAME).map_err(bus_err)?;
        if let Some(p) = &path {
            rule = rule.path(p.as_str()).map_err(bus_err)?;
        }
        let mut stream = zbus::MessageStream::for_match_rule(rule.build(), conn, Some(256)).await.map_err(bus_err)?;
        // Subscribed first, then read: a job that finishes in between is seen as finished here.
        let mut state = match &path {
            Some(p) => all_properties(conn, p.clone(), JOB_IFACE).await?,
            None => serde_json::Value::Null,
        };
        if path.is_some() && state["Result"].as_str().is_some_and(|r| !r.is_empty()) {
            on_event(&serde_json::json!({"event": "finished", "path": path, "properties": state}));
            return Ok(state);
        }
        while let Some(msg) = stream.next().await {
            let Ok(msg) = msg else { continue };
            let h = msg.header();
            let member = h.member().map(|m| m.to_string()).unwrap_or_default();
            let p = h.path().map(|p| p.to_string()).unwrap_or_default();
            let body = msg.body();
            let event = match member.as_str() {
                "PropertiesChanged" => {
                    let Ok((iface, changed, _inv)) =
                        body.deserialize::<(String, HashMap<String, OwnedValue>, Vec<String>)>()
                    else {
                        continue;
                    };
                    if iface != JOB_IFACE {
                        continue;
                    }
                    let c = props_json(&changed);
                    if path.is_some()
                        && let (Some(obj), Some(cm)) = (state.as_object_mut(), c.as_object())
                    {
                        for (k, v) in cm {
                            obj.insert(k.clone(), v.clone());
                        }
                    }
                    serde_json::json!({"event": "changed", "path": p, "properties": c})
                }
                "Completed" => {
                    let Ok((result, code, message)) = body.deserialize::<(String, String, String)>() else { continue };
                    serde_json::json!({"event": "completed", "path": p, "result": result, "error_code": code, "message": message})
                }
                "JobFinished" => {
                    let Ok((job, result, code)) =
                        body.deserialize::<(zbus::zvariant::OwnedObjectPath, String, String)>()
                    else {
                        continue;
                    };
                    serde_json::json!({"event": "job-finished", "path": job.as_str(), "result": result, "error_code": code})
                }
                _ => continue,
            };
            on_event(&event);
            if path.is_some() && event["event"] == "completed" {
                let done = all_properties(conn, path.clone().unwrap_or_default(), JOB_IFACE).await.unwrap_or(state);
                return Ok(done);
            }
        }
        Ok(state)
    }
}
