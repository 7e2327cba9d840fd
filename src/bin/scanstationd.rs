//! `scanstationd` — the station daemon. Thin: arguments, logging, the runtime; the work is in
//! `scanstation::daemon`.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::Parser;
use scanstation::daemon::config::{Bus, Config, LogFormat};

#[derive(Parser)]
#[command(name = "scanstationd", version, about = "scanstation daemon: watch folders, job queue, D-Bus, systemd")]
struct Args {
    /// The configuration file (see config/scanstation.toml).
    #[arg(long, default_value = "/etc/scanstation/scanstation.toml")]
    config: PathBuf,
    /// Serve on the session bus instead of the configured one (tests, development).
    #[arg(long)]
    session: bool,
    /// Validate the configuration, print the effective values and their digest, and exit.
    #[arg(long)]
    check_config: bool,
}

fn init_logging(format: LogFormat) {
    use tracing_subscriber::prelude::*;
    let filter = tracing_subscriber::filter::LevelFilter::INFO;
    let journald = matches!(format, LogFormat::Journald)
        || (matches!(format, LogFormat::Auto)
            && std::path::Path::new("/run/systemd/journal/socket").exists()
            && std::env::var_os("JOURNAL_STREAM").is_some());
    if journald && let Ok(layer) = tracing_journald::layer().map(|l| l.with_field_prefix(None)) {
        tracing_subscriber::registry().with(layer.with_filter(filter)).init();
        return;
    }
    let fmt = tracing_subscriber::fmt::layer().with_writer(std::io::stderr).with_ansi(false);
    tracing_subscriber::registry().with(fmt.with_filter(filter)).init();
}

fn main() -> ExitCode {
    let args = Args::parse();
    let mut cfg = match Config::load(&args.config) {
        Ok(c) => c,
        Err(e) => {
            eprintln!("scanstationd: {e}");
            return ExitCode::from(78); // EX_CONFIG
        }
    };
    if args.session {
        cfg.bus = Bus::Session;
    }
    if args.check_config {
        println!("{}", cfg.effective_json());
        println!("digest {}", cfg.digest());
        return ExitCode::SUCCESS;
    }
    init_logging(cfg.log_format);
    let rt = match tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build() {
        Ok(rt) => rt,
        Err(e) => {
            eprintln!("scanstationd: cannot start the async runtime: {e}");
            return ExitCode::FAILURE;
        }
    };
    match rt.block_on(scanstation::daemon::run(cfg)) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            tracing::error!(error = %e, "start-up failed");
            eprintln!("scanstationd: {e}");
            ExitCode::FAILURE
        }
    }
}
