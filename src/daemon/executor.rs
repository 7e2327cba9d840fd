//! `[executor]`: where a job's conversion runs — on the station's own CPU pool (`local`, the default), or on
//! a Slurm cluster (`slurm`), submitted with `sbatch` as `scanstation cluster-run` on the job's work
//! directory ([`super::cluster`]). The settings and their checks; plain data.

use std::path::PathBuf;
use std::time::Duration;

use serde::Deserialize;

/// `[executor]` as written.
#[derive(Deserialize, Default)]
#[serde(deny_unknown_fields)]
pub struct RawExecutor {
    kind: Option<String>,
    partition: Option<String>,
    account: Option<String>,
    time_limit: Option<String>,
    cpus: Option<u32>,
    binary: Option<PathBuf>,
    sbatch_args: Option<Vec<String>>,
    poll: Option<String>,
}

/// Where conversions run.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ExecutorKind {
    /// The station's CPU pool.
    Local,
    /// A Slurm cluster (`sbatch`, `squeue`, `scontrol`, `scancel`, `sacct` on the PATH; `SLURM_CONF` as the
    /// site sets it).
    Slurm,
}

/// The validated `[executor]`.
#[derive(Clone, Debug, PartialEq, serde::Serialize)]
pub struct ExecutorConfig {
    /// Local or Slurm.
    pub kind: ExecutorKind,
    /// `--partition` (empty: the cluster's default).
    pub partition: String,
    /// `--account` (empty: the submitter's default).
    pub account: String,
    /// `--time`, minutes.
    pub time_limit_min: u32,
    /// `--cpus-per-task`.
    pub cpus: u32,
    /// The `scanstation` binary's path on the nodes.
    pub binary: PathBuf,
    /// Further `sbatch` arguments, as given (e.g. `--qos=scan`, `--constraint=avx2`).
    pub sbatch_args: Vec<String>,
    /// How often a running cluster job's state and progress are read.
    #[serde(with = "super::config::secs")]
    pub poll: Duration,
}

impl Default for ExecutorConfig {
    fn default() -> Self {
        ExecutorConfig {
            kind: ExecutorKind::Local,
            partition: String::new(),
            account: String::new(),
            time_limit_min: 60,
            cpus: 2,
            binary: PathBuf::from("/usr/bin/scanstation"),
            sbatch_args: Vec::new(),
            poll: Duration::from_millis(500),
        }
    }
}

/// Parse a Slurm time limit: `MINUTES`, `MM:SS`, `HH:MM:SS`, `D-HH[:MM[:SS]]`; minutes, rounded up.
///
/// # Errors
/// A message naming the value and the forms there are.
pub fn parse_time_limit(s: &str) -> Result<u32, String> {
    let bad = || format!("{s:?} is not a Slurm time limit (MINUTES, MM:SS, HH:MM:SS or D-HH:MM:SS)");
    let (days, rest) = match s.split_once('-') {
        Some((d, r)) => (d.trim().parse::<u32>().map_err(|_| bad())?, r),
        None => (0, s),
    };
    let parts: Vec<u32> =
        rest.split(':').map(|p| p.trim().parse::<u32>().map_err(|_| bad())).collect::<Result<_, _>>()?;
    let seconds: u64 = match (s.contains('-'), parts.as_slice()) {
        (false, [m]) => u64::from(*m) * 60,
        (false, [m, sec]) => u64::from(*m) * 60 + u64::from(*sec),
        (false, [h, m, sec]) => u64::from(*h) * 3600 + u64::from(*m) * 60 + u64::from(*sec),
        (true, [h]) => u64::from(*h) * 3600,
        (true, [h, m]) => u64::from(*h) * 3600 + u64::from(*m) * 60,
        (true, [h, m, sec]) => u64::from(*h) * 3600 + u64::from(*m) * 60 + u64::from(*sec),
        _ => return Err(bad()),
    } + u64::from(days) * 86_400;
    let minutes = seconds.div_ceil(60);
    if minutes == 0 || minutes > 365 * 24 * 60 {
        return Err(format!("{s:?}: a time limit is 1 minute to 365 days"));
    }
    Ok(minutes as u32)
}

/// A duration parser: (key, value as written, default) → the duration, or (key, reason).
pub type DurationOf<'a> = dyn Fn(&str, &Option<String>, &str) -> Result<Duration, (String, String)> + 'a;

/// Validate `[executor]`; `poll` parsed by the config's duration parser.
///
/// # Errors
/// `(key, reason)`: an unknown kind, a bad time limit, 0 or more than 1024 CPUs, a relative binary path, an
/// `sbatch` argument that is not an option or that sets what the station sets itself.
pub fn parse(raw: RawExecutor, duration: &DurationOf<'_>) -> Result<ExecutorConfig, (String, String)> {
    let k = |key: &str| format!("executor.{key}");
    let kind = match raw.kind.as_deref().unwrap_or("local") {
        "local" => ExecutorKind::Local,
        "slurm" => ExecutorKind::Slurm,
        o => return Err((k("kind"), format!("{o:?} is neither \"local\" nor \"slurm\""))),
    };
    let d = ExecutorConfig::default();
    let time_limit_min = match &raw.time_limit {
        Some(t) => parse_time_limit(t).map_err(|r| (k("time_limit"), r))?,
        None => d.time_limit_min,
    };
    let cpus = raw.cpus.unwrap_or(d.cpus);
    if !(1..=1024).contains(&cpus) {
        return Err((k("cpus"), format!("{cpus} is outside 1..=1024")));
    }
    let binary = raw.binary.unwrap_or(d.binary);
    if !binary.is_absolute() {
        return Err((
            k("binary"),
            format!("{} is not an absolute path (the binary's path on the nodes)", binary.display()),
        ));
    }
    let sbatch_args = raw.sbatch_args.unwrap_or_default();
    // What the station sets itself: a site may not override it by accident.
    const OWN: [&str; 11] =
        ["--job-name", "-J", "--mem", "--output", "-o", "--error", "-e", "--chdir", "-D", "--parsable", "--wrap"];
    for a in &sbatch_args {
        if !a.starts_with('-') {
            return Err((k("sbatch_args"), format!("{a:?} is not an option (each item one `--key=value`)")));
        }
        let key = a.split('=').next().unwrap_or(a);
        if OWN.contains(&key) {
            return Err((k("sbatch_args"), format!("{key} is set by the station (from the job and its budget)")));
        }
    }
    let poll = duration(&k("poll"), &raw.poll, "500ms")?;
    if poll < Duration::from_millis(50) || poll > Duration::from_secs(60) {
        return Err((k("poll"), "between 50ms and 60s".into()));
    }
    let text = |v: Option<String>| v.unwrap_or_default().trim().to_string();
    Ok(ExecutorConfig {
        kind,
        partition: text(raw.partition),
        account: text(raw.account),
        time_limit_min,
        cpus,
        binary,
        sbatch_args,
        poll,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn time_limits_parse_in_slurms_forms() {
        assert_eq!(parse_time_limit("30"), Ok(30));
        assert_eq!(parse_time_limit("30:30"), Ok(31));
        assert_eq!(parse_time_limit("2:00:00"), Ok(120));
        assert_eq!(parse_time_limit("1-2"), Ok(26 * 60));
        assert_eq!(parse_time_limit("1-00:30:00"), Ok(24 * 60 + 30));
        assert!(parse_time_limit("soon").unwrap_err().contains("MINUTES"));
        assert!(parse_time_limit("0").unwrap_err().contains("1 minute"));
    }

    #[test]
    fn the_stations_own_sbatch_options_are_refused() {
        let dur = |_: &str, _: &Option<String>, _: &str| Ok(Duration::from_millis(500));
        let raw = |args: &[&str]| RawExecutor {
            kind: Some("slurm".into()),
            sbatch_args: Some(args.iter().map(|s| s.to_string()).collect()),
            ..Default::default()
        };
        assert!(parse(raw(&["--qos=scan"]), &dur).is_ok());
        assert!(parse(raw(&["--mem=4G"]), &dur).unwrap_err().1.contains("set by the station"));
        assert!(parse(raw(&["qos"]), &dur).unwrap_err().1.contains("not an option"));
        let e = parse(RawExecutor { kind: Some("k8s".into()), ..Default::default() }, &dur).unwrap_err();
        assert_eq!(e.0, "executor.kind");
    }
}
