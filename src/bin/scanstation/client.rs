//! The D-Bus client commands (thin: the work is in `scanstation::daemon::client::ops`).

use std::process::ExitCode;

use scanstation::Error;

use crate::Command;
use crate::args::{CancelArgs, ContinueArgs, JobsArgs, RigAction, RigArgs, StatusArgs, WatchArgs};
use crate::print::{print_json, report_error};

/// Runs a client command against the station's bus; exit status 1 when a followed job failed.
pub fn run(command: &Command, json: bool) -> ExitCode {
    use scanstation::daemon::client::ops;
    let rt = match tokio::runtime::Builder::new_current_thread().enable_all().build() {
        Ok(rt) => rt,
        Err(e) => return report_error(&Error::internal(format!("cannot start the async runtime: {e}")), json),
    };
    let r: Result<bool, Error> = rt.block_on(async {
        match command {
            Command::Status(StatusArgs { session }) => {
                let conn = ops::connect(*session).await?;
                let s = ops::status(&conn).await?;
                if json {
                    print_json(&s);
                } else {
                    for (k, v) in s.as_object().into_iter().flatten() {
                        outln!("{k:<14} {v}");
                    }
                }
                Ok(true)
            }
            Command::Jobs(JobsArgs { session }) => {
                let conn = ops::connect(*session).await?;
                let jobs = ops::jobs(&conn).await?;
                if json {
                    print_json(&serde_json::json!({ "jobs": jobs }));
                } else {
                    outln!("{:<26}  {:<10}  {:>6}  {:<9}  {:<22}  input", "id", "state", "done", "stage", "error");
                    for j in &jobs {
                        outln!(
                            "{:<26}  {:<10}  {:>5.1}%  {:<9}  {:<22}  {}",
                            j["Id"].as_str().unwrap_or(""),
                            j["State"].as_str().unwrap_or(""),
                            j["Progress"].as_f64().unwrap_or(0.0) * 100.0,
                            j["Stage"].as_str().unwrap_or(""),
                            j["ErrorCode"].as_str().unwrap_or(""),
                            j["Input"].as_str().unwrap_or("")
                        );
                    }
                }
                Ok(true)
            }
            Command::Submit(a) => {
                let conn = ops::connect(a.session).await?;
                let job = job_options(a.vertices, a.tolerance, a.seed, a.accept_degraded);
                let path = ops::submit(&conn, &a.file, &job).await?;
                follow(&conn, &path, a.wait, json).await
            }
            Command::Scan(a) => {
                let conn = ops::connect(a.session).await?;
                let o = ops::ScanOptions {
                    views: a.views,
                    step_deg: a.step_deg,
                    tilts: a.tilts.clone(),
                    coverage: a.coverage,
                    max_views: a.max_views,
                    passes: a.passes,
                    name: a.name.clone(),
                    fea: a.fea.clone(),
                    job: job_options(a.vertices, a.tolerance, a.seed, a.accept_degraded),
                };
                let path = ops::scan(&conn, &o).await?;
                follow(&conn, &path, a.wait, json).await
            }
            Command::Cancel(CancelArgs { id, session }) => {
                let conn = ops::connect(*session).await?;
                ops::cancel(&conn, id).await?;
                if json {
                    print_json(&serde_json::json!({ "cancelled": ops::job_path(id) }));
                }
                Ok(true)
            }
            Command::Continue(ContinueArgs { id, session }) => {
                let conn = ops::connect(*session).await?;
                ops::proceed(&conn, id).await?;
                if json {
                    print_json(&serde_json::json!({ "continued": ops::job_path(id) }));
                }
                Ok(true)
            }
            Command::Watch(WatchArgs { id, session }) => {
                let conn = ops::connect(*session).await?;
                let done = ops::watch(&conn, id.as_deref(), &mut event_printer(json)).await?;
                Ok(id.is_none() || done["Result"] == "succeeded")
            }
            Command::Rig(RigArgs { action, session }) => {
                let conn = ops::connect(*session).await?;
                rig(&conn, action, json).await?;
                Ok(true)
            }
            _ => Ok(true),
        }
    });
    match r {
        Ok(true) => ExitCode::SUCCESS,
        Ok(false) => ExitCode::from(1),
        Err(e) => report_error(&e, json),
    }
}

/// `scanstation rig …`: one call, its result as text or JSON.
async fn rig(conn: &zbus::Connection, action: &RigAction, json: bool) -> Result<(), Error> {
    use scanstation::daemon::client::ops;
    use std::io::IsTerminal;
    let started = std::time::Instant::now();
    let out = match action {
        RigAction::Status => {
            let s = ops::rig_status(conn).await?;
            if !json {
                for (device, props) in s.as_object().into_iter().flatten() {
                    match props.as_object() {
                        None => outln!("{device}: not configured"),
                        Some(p) => {
                            outln!("{device}:");
                            for (k, v) in p {
                                outln!("  {k:<20} {v}");
                            }
                        }
                    }
                }
            }
            s
        }
        RigAction::Home => {
            if !json && std::io::stderr().is_terminal() {
                eprintln!("homing…");
            }
            ops::rig_home(conn).await?;
            serde_json::json!({ "homed": true, "seconds": started.elapsed().as_secs_f64() })
        }
        RigAction::Move { degrees, tilt } => {
            if !json && std::io::stderr().is_terminal() {
                eprintln!("turning to {degrees}°…");
            }
            let reached = ops::rig_move(conn, *degrees, *tilt).await?;
            let seconds = started.elapsed().as_secs_f64();
            serde_json::json!({ "target": degrees, "tilt": tilt, "reached": reached, "seconds": seconds })
        }
        RigAction::Fire { channel } => {
            if !json && std::io::stderr().is_terminal() {
                eprintln!("firing channel {channel}…");
            }
            let sent = ops::rig_fire(conn, *channel).await?;
            serde_json::json!({ "channel": channel, "sent_usec": sent, "seconds": started.elapsed().as_secs_f64() })
        }
    };
    if json {
        print_json(&out);
    } else if !matches!(action, RigAction::Status) {
        for (k, v) in out.as_object().into_iter().flatten() {
            outln!("{k:<10} {v}");
        }
    }
    Ok(())
}

/// A new job's path printed, or with `wait` the job followed to its end: whether it succeeded.
async fn follow(conn: &zbus::Connection, path: &str, wait: bool, json: bool) -> scanstation::Result<bool> {
    if !wait {
        if json {
            print_json(&serde_json::json!({ "job": path }));
        } else {
            outln!("{path}");
        }
        return Ok(true);
    }
    let done = scanstation::daemon::client::ops::watch(conn, Some(path), &mut event_printer(json)).await?;
    if !json {
        outln!("{} {}", done["Result"], done["ErrorCode"]);
    }
    Ok(done["Result"] == "succeeded")
}

/// A job's options from the command line (`accept_degraded` only when asked: the daemon's default otherwise).
fn job_options(
    vertices: Option<u32>,
    tolerance: Option<f64>,
    seed: Option<u64>,
    accept_degraded: bool,
) -> scanstation::daemon::config::JobOptions {
    scanstation::daemon::config::JobOptions {
        vertices: vertices.map(|v| v as usize),
        tolerance,
        seed,
        accept_degraded: accept_degraded.then_some(true),
    }
}

/// How `watch` shows the station's events: a JSON line each with `--json` or when stdout is not a terminal,
/// else a progress bar per job, what a scan asks a person to do (`OperatorAction`), and its result when it ends (a `finished` event, for a job that had already
/// ended, prints nothing here: the caller prints the result).
fn event_printer(json: bool) -> impl FnMut(&serde_json::Value) + Send {
    use std::io::{IsTerminal, Write};
    let lines = json || !std::io::stdout().is_terminal();
    move |event: &serde_json::Value| {
        let mut out = std::io::stdout();
        let p = event["path"].as_str().unwrap_or("");
        let id = p.rsplit('/').next().unwrap_or("");
        let asked = event["properties"]["OperatorAction"].as_str().filter(|a| !a.is_empty());
        if lines {
            let _ = writeln!(out, "{event}");
        } else if let Some(what) = asked.filter(|_| event["event"] == "changed") {
            // A scan waits for a person (the object turned over between passes).
            let _ = writeln!(out, "\n{id} waits for you: {what}\n  then: scanstation continue {id}");
        } else if let Some(pr) = event["properties"]["Progress"].as_f64().filter(|_| event["event"] == "changed") {
            let n = (pr * 30.0).round() as usize;
            let stage = event["properties"]["Stage"].as_str().unwrap_or("");
            let bar = format!("{}{}", "#".repeat(n.min(30)), ".".repeat(30 - n.min(30)));
            let _ = write!(out, "\r{id} [{bar}] {:5.1}% {stage:<10}", pr * 100.0);
        } else if event["event"] == "completed" || event["event"] == "job-finished" {
            let _ = writeln!(out, "\n{id} {} {}", event["result"], event["error_code"]);
        }
        let _ = out.flush();
    }
}
