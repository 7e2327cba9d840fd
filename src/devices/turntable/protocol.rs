//! Grbl 1.1's serial protocol, as the turntable's firmware speaks it: what the host sends and what comes
//! back, parsed without I/O (the driver in [`super::driver`] and the simulator in [`super::sim`] both
//! use it).
//!
//! The turntable is Grbl's axis X, in degrees. The host sends one line at a time (at most
//! [`MAX_LINE_BYTES`], well inside Grbl's 128-byte receive buffer) and waits for its `ok` or `error:n`; the
//! real-time bytes (`?` status, `!` hold, `~` resume, Ctrl-X reset) are single bytes outside the line
//! stream. After a reset Grbl prints its banner `Grbl 1.1h ['$' for help]`; with homing enabled it then
//! says `[MSG:'$H'|'$X' to unlock]` and refuses motion until homed or unlocked.

/// Grbl's receive buffer (bytes).
pub const RX_BUFFER_BYTES: usize = 128;

/// Longest line the host sends, newline included (Grbl's line buffer is 80 bytes).
pub const MAX_LINE_BYTES: usize = 80;

/// Longest line the host accepts from the firmware; longer ones are garbage (Grbl's longest report, the
/// status report with every field, is about 100 bytes).
pub const MAX_REPLY_BYTES: usize = 256;

/// The real-time status query.
pub const STATUS_QUERY: u8 = b'?';
/// The real-time feed hold (stops motion, decelerating).
pub const FEED_HOLD: u8 = b'!';
/// The real-time soft reset (Ctrl-X).
pub const SOFT_RESET: u8 = 0x18;

/// The firmware version the driver speaks to (the banner's major.minor).
pub const SUPPORTED_VERSION: &str = "1.1";

/// A machine state of a status report.
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum MachineState {
    /// At rest, ready.
    Idle,
    /// Moving.
    Run,
    /// In a feed hold.
    Hold,
    /// Jogging.
    Jog,
    /// Locked after a reset with homing enabled, or after an alarm.
    Alarm,
    /// A door switch opened.
    Door,
    /// Check mode.
    Check,
    /// Homing.
    Home,
    /// Asleep.
    Sleep,
}

impl MachineState {
    fn parse(s: &str) -> Option<MachineState> {
        // Hold and Door carry a sub-state after a colon (`Hold:0`).
        Some(match s.split(':').next()? {
            "Idle" => MachineState::Idle,
            "Run" => MachineState::Run,
            "Hold" => MachineState::Hold,
            "Jog" => MachineState::Jog,
            "Alarm" => MachineState::Alarm,
            "Door" => MachineState::Door,
            "Check" => MachineState::Check,
            "Home" => MachineState::Home,
            "Sleep" => MachineState::Sleep,
            _ => return None,
        })
    }

    /// The word Grbl prints.
    pub fn as_str(self) -> &'static str {
        match self {
            MachineState::Idle => "Idle",
            MachineState::Run => "Run",
            MachineState::Hold => "Hold:0",
            MachineState::Jog => "Jog",
            MachineState::Alarm => "Alarm",
            MachineState::Door => "Door:0",
            MachineState::Check => "Check",
            MachineState::Home => "Home",
            MachineState::Sleep => "Sleep",
        }
    }
}

/// A status report `<Idle|MPos:12.000,0.000,0.000|FS:0,0>`: the state and the machine position of X.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct StatusReport {
    /// Machine state.
    pub state: MachineState,
    /// Position of axis X (the table), degrees: `MPos` (or `WPos`, whichever the firmware reports).
    pub x: f64,
    /// Position of axis Y (a tilting table's cradle), degrees; 0 when the report has no second value.
    pub y: f64,
    /// Feed rate now (degrees per minute), when reported.
    pub feed: Option<f64>,
}

/// One line from the firmware.
#[derive(Clone, Debug, PartialEq)]
pub enum Reply {
    /// `ok`: the last line was accepted.
    Ok,
    /// `error:n`: the last line was refused.
    Error(u32),
    /// `ALARM:n`: the machine locked itself (a limit, an aborted cycle, a failed homing).
    Alarm(u32),
    /// The banner after a reset: `Grbl 1.1h ['$' for help]` → the version `1.1h`.
    Banner(String),
    /// `[MSG:…]` and other bracketed feedback (`[GC:…]`, `[VER:…]`), the text inside the brackets.
    Feedback(String),
    /// A status report.
    Status(StatusReport),
    /// `$n=v`: one of the board's settings (the answer to `$$`), its number and value.
    Setting(u32, f64),
    /// Other text the driver does not act on (`$N0=` startup blocks, `$I` build info).
    Other(String),
}

impl Reply {
    /// Parse one line (without its line ending). `None` for garbage: empty, not ASCII, or a malformed
    /// report, alarm or error. Garbage is counted and logged by the driver, never acted on.
    pub fn parse(line: &str) -> Option<Reply> {
        let line = line.trim_end_matches('\r');
        if line.is_empty() || !line.is_ascii() || line.len() > MAX_REPLY_BYTES {
            return None;
        }
        if line == "ok" {
            return Some(Reply::Ok);
        }
        if let Some(n) = line.strip_prefix("error:") {
            return n.parse().ok().map(Reply::Error);
        }
        if let Some(n) = line.strip_prefix("ALARM:") {
            return n.parse().ok().map(Reply::Alarm);
        }
        if let Some(rest) = line.strip_prefix("Grbl ") {
            let version = rest.split_whitespace().next()?;
            return Some(Reply::Banner(version.to_string()));
        }
        if let Some(inner) = line.strip_prefix('[').and_then(|l| l.strip_suffix(']')) {
            return Some(Reply::Feedback(inner.to_string()));
        }
        if let Some(inner) = line.strip_prefix('<').and_then(|l| l.strip_suffix('>')) {
            return parse_status(inner).map(Reply::Status);
        }
        if line.starts_with('<') || line.starts_with('[') {
            return None;
        }
        if let Some((n, v)) = line.strip_prefix('$').and_then(|l| l.split_once('='))
            && let (Ok(n), Ok(v)) = (n.parse::<u32>(), v.parse::<f64>())
            && v.is_finite()
        {
            return Some(Reply::Setting(n, v));
        }
        Some(Reply::Other(line.to_string()))
    }
}

/// `Idle|MPos:12.000,0.000,0.000|FS:0,0` → the report.
fn parse_status(inner: &str) -> Option<StatusReport> {
    let mut fields = inner.split('|');
    let state = MachineState::parse(fields.next()?)?;
    let (mut x, mut y, mut feed) = (None, 0.0, None);
    for f in fields {
        if let Some(p) = f.strip_prefix("MPos:").or_else(|| f.strip_prefix("WPos:")) {
            let mut axes = p.split(',');
            x = axes.next()?.parse::<f64>().ok().filter(|v| v.is_finite());
            if let Some(v) = axes.next() {
                y = v.parse::<f64>().ok().filter(|v| v.is_finite())?;
            }
        } else if let Some(fs) = f.strip_prefix("FS:").or_else(|| f.strip_prefix("F:")) {
            feed = fs.split(',').next()?.parse::<f64>().ok().filter(|v| v.is_finite());
        }
    }
    Some(StatusReport { state, x: x?, y, feed })
}

/// Grbl 1.1h's factory settings (`$$` of a board with a fresh EEPROM: `defaults.h`, `DEFAULTS_GENERIC`):
/// homing disabled (`$22=0`), 250 steps per unit (`$100`), 500 units/min top rate (`$110`), 10 units/s²
/// acceleration (`$120`), 200 units of travel (`$130`); the table's unit is the degree.
pub const FACTORY_SETTINGS: [(u32, f64); 34] = [
    (0, 10.0),
    (1, 25.0),
    (2, 0.0),
    (3, 0.0),
    (4, 0.0),
    (5, 0.0),
    (6, 0.0),
    (10, 1.0),
    (11, 0.010),
    (12, 0.002),
    (13, 0.0),
    (20, 0.0),
    (21, 0.0),
    (22, 0.0),
    (23, 0.0),
    (24, 25.0),
    (25, 500.0),
    (26, 250.0),
    (27, 1.0),
    (30, 1000.0),
    (31, 0.0),
    (32, 0.0),
    (100, 250.0),
    (101, 250.0),
    (102, 250.0),
    (110, 500.0),
    (111, 500.0),
    (112, 500.0),
    (120, 10.0),
    (121, 10.0),
    (122, 10.0),
    (130, 200.0),
    (131, 200.0),
    (132, 200.0),
];

/// What the driver reads from the board's settings (`$$`) for axis X, the table, in degrees.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize)]
pub struct BoardSettings {
    /// Homing enabled (`$22`): the board locks after a reset until `$H` (or `$X`).
    pub homing: bool,
    /// Steps per degree (`$100`).
    pub steps_per_degree: f64,
    /// Top rate, degrees per minute (`$110`): a move's `F` above it is clamped to it.
    pub max_rate: f64,
    /// Acceleration, degrees per second² (`$120`).
    pub accel: f64,
}

impl BoardSettings {
    /// A factory-fresh board's ([`FACTORY_SETTINGS`]; a unit test keeps the two equal).
    pub const FACTORY: BoardSettings =
        BoardSettings { homing: false, steps_per_degree: 250.0, max_rate: 500.0, accel: 10.0 };

    /// The X axis' settings from `$n=v` pairs.
    ///
    /// # Errors
    /// A message naming the first of `$22`, `$100`, `$110`, `$120` that is missing or not positive (`$22`: 0
    /// or 1).
    pub fn from_settings(settings: &[(u32, f64)]) -> std::result::Result<BoardSettings, String> {
        let get = |n: u32| settings.iter().rev().find(|(k, _)| *k == n).map(|&(_, v)| v);
        let positive = |n: u32| match get(n) {
            Some(v) if v > 0.0 => Ok(v),
            Some(v) => Err(format!("${n}={v} is not positive")),
            None => Err(format!("the board's settings have no ${n}")),
        };
        let homing = match get(22) {
            Some(v) if v == 0.0 || v == 1.0 => v == 1.0,
            Some(v) => return Err(format!("$22={v} is neither 0 nor 1")),
            None => return Err("the board's settings have no $22".into()),
        };
        Ok(BoardSettings { homing, steps_per_degree: positive(100)?, max_rate: positive(110)?, accel: positive(120)? })
    }

    /// The top speed, degrees per second.
    pub fn max_speed(&self) -> f64 {
        self.max_rate / 60.0
    }
}

/// Whether a banner's version (`1.1h`) is one the driver speaks to.
pub fn version_supported(version: &str) -> bool {
    version.strip_prefix(SUPPORTED_VERSION).is_some_and(|rest| rest.chars().all(|c| c.is_ascii_lowercase()))
}

/// What an `error:n` means (Grbl 1.1's table, the codes a turntable can meet).
pub fn error_text(code: u32) -> &'static str {
    match code {
        1 => "G-code words consist of a letter and a value; the letter was not found",
        2 => "numeric value format is not valid or missing an expected value",
        3 => "Grbl '$' system command was not recognized or supported",
        8 => "Grbl '$' command cannot be used unless Grbl is idle",
        9 => "G-code locked out during alarm or jog state",
        15 => "jog target exceeds machine travel",
        20 => "unsupported or invalid g-code command",
        22 => "feed rate has not yet been set or is undefined",
        _ => "refused by the firmware",
    }
}

/// What an `ALARM:n` means (Grbl 1.1's table).
pub fn alarm_text(code: u32) -> &'static str {
    match code {
        1 => "hard limit triggered",
        2 => "soft limit: the target exceeds machine travel",
        3 => "reset while in motion: position lost, re-homing recommended",
        4 => "probe fail",
        5 => "probe fail",
        6 => "homing fail: reset during the homing cycle",
        7 => "homing fail: door opened during homing",
        8 => "homing fail: pull-off did not clear the limit switch",
        9 => "homing fail: the limit switch was not found",
        10 => "homing fail: second switch not found",
        _ => "alarm",
    }
}

/// The absolute move to `degrees` at `feed` degrees per minute: `G90 G1 X45.0000 F720.0`.
pub fn move_line(degrees: f64, feed: f64) -> String {
    format!("G90 G1 X{degrees:.4} F{feed:.1}\n")
}

/// A tilting table's absolute move: the table to `degrees` (X) and the cradle to `tilt` (Y) along one
/// straight path at `feed` degrees per minute: `G90 G1 X45.0000 Y-20.0000 F720.0`.
pub fn move_line_tilted(degrees: f64, tilt: f64, feed: f64) -> String {
    format!("G90 G1 X{degrees:.4} Y{tilt:.4} F{feed:.1}\n")
}

/// Time a move of `distance` degrees takes at top speed `speed` (°/s) with acceleration `accel` (°/s²): a
/// trapezoid, or a triangle when the move is too short to reach the top speed. Seconds.
pub fn move_seconds(distance: f64, speed: f64, accel: f64) -> f64 {
    let d = distance.abs();
    if !(speed > 0.0 && accel > 0.0) || d == 0.0 {
        return 0.0;
    }
    let ramp = speed * speed / accel; // distance to accelerate and to stop
    if d >= ramp { d / speed + speed / accel } else { 2.0 * (d / accel).sqrt() }
}

/// Position after `t` seconds of a move from `from` to `to` (the same trapezoid).
pub fn position_at(from: f64, to: f64, speed: f64, accel: f64, t: f64) -> f64 {
    let d = (to - from).abs();
    let total = move_seconds(d, speed, accel);
    if t >= total || d == 0.0 {
        return to;
    }
    let sign = (to - from).signum();
    let peak = speed.min((d * accel).sqrt()); // top speed reached
    let t_acc = peak / accel;
    let cruise = total - 2.0 * t_acc;
    let s = if t < t_acc {
        0.5 * accel * t * t
    } else if t < t_acc + cruise {
        0.5 * accel * t_acc * t_acc + peak * (t - t_acc)
    } else {
        let left = total - t;
        d - 0.5 * accel * left * left
    };
    from + sign * s.clamp(0.0, d)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn replies_of_grbl_1_1_parse() {
        assert_eq!(Reply::parse("ok\r"), Some(Reply::Ok));
        assert_eq!(Reply::parse("error:9"), Some(Reply::Error(9)));
        assert_eq!(Reply::parse("ALARM:1"), Some(Reply::Alarm(1)));
        assert_eq!(Reply::parse("Grbl 1.1h ['$' for help]"), Some(Reply::Banner("1.1h".into())));
        assert_eq!(Reply::parse("[MSG:'$H'|'$X' to unlock]"), Some(Reply::Feedback("MSG:'$H'|'$X' to unlock".into())));
        let s = Reply::parse("<Run|MPos:12.345,0.000,0.000|FS:720,0|WCO:0.000,0.000,0.000>");
        let run = StatusReport { state: MachineState::Run, x: 12.345, y: 0.0, feed: Some(720.0) };
        assert_eq!(s, Some(Reply::Status(run)));
        let s = Reply::parse("<Hold:0|WPos:-1.5,30.25,0|Bf:15,128|FS:0,0>");
        let hold = StatusReport { state: MachineState::Hold, x: -1.5, y: 30.25, feed: Some(0.0) };
        assert_eq!(s, Some(Reply::Status(hold)));
        assert_eq!(move_line_tilted(45.0, -20.0, 720.0), "G90 G1 X45.0000 Y-20.0000 F720.0\n");
        assert_eq!(Reply::parse("$100=250.000"), Some(Reply::Setting(100, 250.0)));
        assert_eq!(Reply::parse("$N0="), Some(Reply::Other("$N0=".into())));
        assert_eq!(Reply::parse("$110=inf"), Some(Reply::Other("$110=inf".into())));
    }

    /// A factory-fresh board: homing off, 500 °/min (8.3 °/s), 10 °/s²; a board without `$110` is named.
    #[test]
    fn board_settings_from_the_factory_defaults() {
        let b = BoardSettings::from_settings(&FACTORY_SETTINGS).unwrap();
        assert_eq!(b, BoardSettings { homing: false, steps_per_degree: 250.0, max_rate: 500.0, accel: 10.0 });
        assert_eq!(b, BoardSettings::FACTORY);
        assert!((b.max_speed() - 500.0 / 60.0).abs() < 1e-12);
        let without: Vec<(u32, f64)> = FACTORY_SETTINGS.iter().copied().filter(|s| s.0 != 110).collect();
        assert_eq!(BoardSettings::from_settings(&without).unwrap_err(), "the board's settings have no $110");
        let mut homing = FACTORY_SETTINGS.to_vec();
        homing.push((22, 1.0));
        assert!(BoardSettings::from_settings(&homing).unwrap().homing, "the last value of a setting counts");
        homing.push((22, 2.0));
        assert!(BoardSettings::from_settings(&homing).unwrap_err().contains("$22=2"));
    }

    /// Line noise (the bytes of a replug, a baud mismatch) is garbage, never a reply.
    #[test]
    fn garbage_is_not_a_reply() {
        for g in [
            "",
            "error:",
            "error:x",
            "ALARM:",
            "<Idle>",
            "<Flying|MPos:0,0,0>",
            "<Idle|MPos:nan,0,0>",
            "<Idle|MPos:1,0,0",
            "\u{fffd}ok",
            "[MSG",
        ] {
            assert_eq!(Reply::parse(g), None, "{g:?}");
        }
        assert_eq!(Reply::parse(&"x".repeat(300)), None);
    }

    #[test]
    fn versions_and_move_lines() {
        assert!(version_supported("1.1h") && version_supported("1.1f") && version_supported("1.1"));
        assert!(!version_supported("0.9j") && !version_supported("1.10") && !version_supported("Horus"));
        let l = move_line(45.0, 720.0);
        assert_eq!(l, "G90 G1 X45.0000 F720.0\n");
        assert!(move_line(-123456.789, 99999.0).len() <= MAX_LINE_BYTES);
    }

    /// The trapezoid: 90° at 60 °/s with 120 °/s² takes 1.5 + 0.5 s; 10° never reaches the top speed
    /// (a triangle of 2√(10/120) s); positions are continuous and end at the target.
    #[test]
    fn move_timing_follows_the_trapezoid() {
        assert!((move_seconds(90.0, 60.0, 120.0) - 2.0).abs() < 1e-12);
        assert!((move_seconds(-10.0, 60.0, 120.0) - 2.0 * (10.0f64 / 120.0).sqrt()).abs() < 1e-12);
        let mut last = 0.0;
        for k in 0..=200 {
            let p = position_at(0.0, 90.0, 60.0, 120.0, k as f64 * 0.01);
            assert!(p >= last - 1e-12 && p - last < 0.61, "t = {}: {last} → {p}", k as f64 * 0.01);
            last = p;
        }
        assert_eq!(position_at(0.0, 90.0, 60.0, 120.0, 2.0), 90.0);
        assert!((position_at(0.0, 90.0, 60.0, 120.0, 1.0) - 45.0).abs() < 1e-9, "symmetric");
        assert!((position_at(10.0, 0.0, 60.0, 120.0, 0.1) - 9.4).abs() < 1e-9);
    }
}
