//! Process memory figures (Linux `/proc/self`): resident set, its high-water mark, and a per-stage meter.

use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

/// A `/proc/self/status` figure in MiB (`"VmRSS:"`, `"VmHWM:"`); `None` where unavailable.
pub fn status_mib(key: &str) -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with(key))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}

/// Reset the kernel's peak-RSS counter (`VmHWM`) to the current RSS; false when not permitted.
pub fn reset_peak() -> bool {
    std::fs::write("/proc/self/clear_refs", "5").is_ok()
}

/// Wall time and peak resident memory of one stage. The high-water mark is reset at the start where
/// `/proc/self/clear_refs` allows it; a sampler thread also polls `VmRSS` every 5 ms, so the figure is per
/// stage even where the reset is refused.
pub struct StageMeter {
    start: Instant,
    hwm_reset: bool,
    stop: Arc<AtomicBool>,
    sampler: Option<JoinHandle<f64>>,
}

impl StageMeter {
    /// Start measuring.
    pub fn start() -> Self {
        let hwm_reset = reset_peak();
        let stop = Arc::new(AtomicBool::new(false));
        let flag = stop.clone();
        let sampler = std::thread::Builder::new()
            .name("rss-sampler".into())
            .spawn(move || {
                let mut peak: f64 = 0.0;
                loop {
                    peak = peak.max(status_mib("VmRSS:").unwrap_or(0.0));
                    if flag.load(Ordering::Relaxed) {
                        return peak;
                    }
                    std::thread::sleep(Duration::from_millis(5));
                }
            })
            .ok();
        StageMeter { start: Instant::now(), hwm_reset, stop, sampler }
    }

    /// Seconds since the start and the peak resident memory in MiB (`None` where unavailable).
    pub fn finish(self) -> (f64, Option<f64>) {
        let seconds = self.start.elapsed().as_secs_f64();
        self.stop.store(true, Ordering::Relaxed);
        let sampled = self.sampler.and_then(|h| h.join().ok());
        let hwm = if self.hwm_reset { status_mib("VmHWM:") } else { None };
        let peak = match (hwm, sampled) {
            (Some(a), Some(b)) => Some(a.max(b)),
            (a, b) => a.or(b).filter(|m| *m > 0.0),
        };
        (seconds, peak)
    }
}
