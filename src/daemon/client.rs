//! Client proxies for the station's D-Bus API (used by `scanstation status|jobs|submit|cancel|watch`).

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
    #[zbus(signal)]
    fn completed(&self, result: String, error_code: String, message: String) -> zbus::Result<()>;
}
