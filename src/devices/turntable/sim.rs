//! A simulated Grbl 1.1 turntable: the firmware's replies to the bytes a host sends, with motion timed by
//! acceleration and top speed, and injectable faults. Pure: the caller feeds bytes and the simulated time,
//! and writes what comes back to a serial line (a pty in [`super::transport`], a pipe in unit tests).
//!
//! What it does, as Grbl does:
//! - a soft reset (Ctrl-X) stops everything and prints the banner; with homing enabled the machine starts in
//!   `Alarm` and says `[MSG:'$H'|'$X' to unlock]`; a reset during a move is `ALARM:3` (position lost);
//! - `$H` homes (taking `home_seconds`, `ok` when done, X = 0; `error:5` when homing is disabled), `$X`
//!   unlocks, `$I` names the build, `$$` lists the settings and `$n=v` changes one (kept across a replug, as
//!   the EEPROM keeps it);
//! - `G90 G1 X… F…` is answered `ok` at once (buffered) and then moves along a trapezoid; `G0` moves at the
//!   top speed; a `Y…` word moves the second axis too (a tilting table's cradle), both axes along one
//!   straight path, the feed along it, as Grbl interpolates; motion while in `Alarm` is `error:9`; an unknown command `error:20`, a bad number `error:2`,
//!   a line over 80 bytes `error:11`;
//! - `?` answers a status report at once, `!` holds (the table stops where it is), `~` resumes.
//!
//! Faults ([`Fault`]): a dropped reply, `error:n` for the next line, `ALARM:n` now, a stalled move (the
//! table stops but the state stays `Run`). Unplugging is the serial line's business ([`super::transport`]).

use std::collections::VecDeque;

use super::protocol::{FACTORY_SETTINGS, FEED_HOLD, MachineState, SOFT_RESET, STATUS_QUERY, position_at};

/// How the simulated firmware behaves. The default is a factory-fresh Grbl 1.1h
/// ([`FACTORY_SETTINGS`]): homing disabled, 500 °/min top rate, 10 °/s².
#[derive(Clone, Debug)]
pub struct SimSettings {
    /// The banner after a reset (a wrong one tests the driver's firmware check).
    pub banner: String,
    /// Homing enabled (`$22=1`): locked in `Alarm` after a reset until `$H` or `$X`.
    pub homing: bool,
    /// Top speed, degrees per second (Grbl's `$110` is per minute).
    pub max_speed: f64,
    /// Acceleration, degrees per second² (`$120`).
    pub accel: f64,
    /// Seconds a homing cycle takes.
    pub home_seconds: f64,
    /// The other settings `$$` lists (`$n=v`), as the EEPROM holds them.
    pub others: std::collections::BTreeMap<u32, f64>,
}

impl Default for SimSettings {
    fn default() -> Self {
        SimSettings {
            banner: "Grbl 1.1h ['$' for help]".into(),
            homing: false,
            max_speed: 500.0 / 60.0,
            accel: 10.0,
            home_seconds: 1.0,
            others: FACTORY_SETTINGS.into_iter().filter(|(n, _)| ![22, 110, 120].contains(n)).collect(),
        }
    }
}

impl SimSettings {
    /// The same board `k` times faster (top rate × k, acceleration × k², homing ÷ k): what a board whose
    /// simulated time runs `k` times faster than the wall clock looks like from the wall clock, so that what
    /// `$$` reports holds for a host that times in wall-clock seconds.
    pub fn faster(mut self, k: f64) -> SimSettings {
        self.max_speed *= k;
        self.accel *= k * k;
        self.home_seconds /= k;
        self
    }

    /// Every setting as `$$` lists it, ascending.
    pub fn listing(&self) -> Vec<(u32, f64)> {
        let mut all = self.others.clone();
        all.insert(22, if self.homing { 1.0 } else { 0.0 });
        all.insert(110, self.max_speed * 60.0);
        all.insert(120, self.accel);
        all.into_iter().collect()
    }

    /// Store `$n=v`; `Err(3)` for a setting Grbl does not have, `Err(4)` for a negative value.
    fn set(&mut self, n: u32, v: f64) -> Result<(), u32> {
        if !(v.is_finite() && v >= 0.0) {
            return Err(4);
        }
        match n {
            22 => self.homing = v != 0.0,
            110 if v > 0.0 => self.max_speed = v / 60.0,
            120 if v > 0.0 => self.accel = v,
            110 | 120 => return Err(4),
            _ if self.others.contains_key(&n) => {
                self.others.insert(n, v);
            }
            _ => return Err(3),
        }
        Ok(())
    }
}

/// A setting as Grbl 1.1 prints it: integers bare (`$22=0`), rates and lengths with three decimals.
fn setting_line(n: u32, v: f64) -> String {
    const FLOATS: [u32; 14] = [11, 12, 24, 25, 27, 100, 101, 102, 110, 111, 112, 120, 121, 122];
    if FLOATS.contains(&n) || (130..=132).contains(&n) {
        format!("${n}={v:.3}\r\n")
    } else {
        format!("${n}={v:.0}\r\n")
    }
}

/// A fault to inject.
#[derive(Clone, Copy, Debug, PartialEq, serde::Deserialize, serde::Serialize)]
#[serde(rename_all = "kebab-case", tag = "fault", content = "code")]
pub enum Fault {
    /// The next `ok` or `error:n` is never sent.
    DropReply,
    /// The next line is answered `error:n` and not executed.
    Error(u32),
    /// `ALARM:n` now: motion stops, the machine locks, the position is lost.
    Alarm(u32),
    /// The move in progress stops where it is, but the state stays `Run` (a stalled motor, a jammed table).
    Stall,
}

/// A move in progress.
#[derive(Clone, Copy, Debug)]
struct Motion {
    /// Start and end of the move, (X, Y).
    from: [f64; 2],
    to: [f64; 2],
    start: f64,
    speed: f64,
}

impl Motion {
    /// The path's length.
    fn length(&self) -> f64 {
        (self.to[0] - self.from[0]).hypot(self.to[1] - self.from[1])
    }

    /// Where the move is `t` seconds in (a trapezoid along the straight path).
    fn at(&self, accel: f64, t: f64) -> [f64; 2] {
        let l = self.length();
        if l == 0.0 {
            return self.to;
        }
        let s = position_at(0.0, l, self.speed, accel, t) / l;
        [self.from[0] + s * (self.to[0] - self.from[0]), self.from[1] + s * (self.to[1] - self.from[1])]
    }
}

/// The simulated firmware.
#[derive(Clone, Debug)]
pub struct GrblSim {
    settings: SimSettings,
    state: MachineState,
    x: f64,
    /// The second axis (a tilting table's cradle), degrees.
    y: f64,
    motion: Option<Motion>,
    queue: VecDeque<([f64; 2], f64)>,
    homing_until: Option<f64>,
    line: Vec<u8>,
    line_too_long: bool,
    drop_reply: bool,
    error_next: Option<u32>,
    stalled: bool,
    feed: f64,
}

impl GrblSim {
    /// A firmware just powered on (its banner is in the first [`GrblSim::input`] or [`GrblSim::tick`]
    /// output after [`GrblSim::power_on`]).
    pub fn new(settings: SimSettings) -> GrblSim {
        let state = if settings.homing { MachineState::Alarm } else { MachineState::Idle };
        GrblSim {
            settings,
            state,
            x: 0.0,
            y: 0.0,
            motion: None,
            queue: VecDeque::new(),
            homing_until: None,
            line: Vec::new(),
            line_too_long: false,
            drop_reply: false,
            error_next: None,
            stalled: false,
            feed: 0.0,
        }
    }

    /// The settings as the EEPROM holds them now (with the `$n=v` changes made since power-on).
    pub fn eeprom(&self) -> &SimSettings {
        &self.settings
    }

    /// What the board prints when it starts (as after a reset; Arduino boards reset when the port opens).
    pub fn power_on(&mut self) -> Vec<u8> {
        self.reset(0.0)
    }

    /// The machine state now.
    pub fn state(&self) -> MachineState {
        self.state
    }

    /// The table's position (degrees) at `now`.
    pub fn position(&mut self, now: f64) -> f64 {
        self.advance(now);
        self.x
    }

    /// The second axis' position (a tilting table's cradle, degrees) at `now`.
    pub fn tilt(&mut self, now: f64) -> f64 {
        self.advance(now);
        self.y
    }

    /// Inject `fault` (at `now`); returns what the firmware prints because of it.
    pub fn inject(&mut self, fault: Fault, now: f64) -> Vec<u8> {
        self.advance(now);
        match fault {
            Fault::DropReply => self.drop_reply = true,
            Fault::Error(n) => self.error_next = Some(n),
            Fault::Stall => self.stalled = true,
            Fault::Alarm(n) => {
                self.stop_all();
                self.state = MachineState::Alarm;
                return format!("ALARM:{n}\r\n").into_bytes();
            }
        }
        Vec::new()
    }

    /// The firmware's answer to `bytes` arriving at simulated time `now` (seconds).
    pub fn input(&mut self, bytes: &[u8], now: f64) -> Vec<u8> {
        let mut out = self.tick(now);
        for &b in bytes {
            match b {
                STATUS_QUERY => out.extend(self.status_line(now)),
                FEED_HOLD => self.hold(now),
                b'~' => {
                    if self.state == MachineState::Hold {
                        self.state = MachineState::Idle;
                    }
                }
                SOFT_RESET => out.extend(self.reset(now)),
                b'\n' => {
                    let line = String::from_utf8_lossy(&self.line).trim().to_string();
                    let too_long = std::mem::take(&mut self.line_too_long);
                    self.line.clear();
                    if too_long {
                        out.extend(self.reply(Err(11)));
                    } else if !line.is_empty() {
                        let r = self.execute(&line, now);
                        out.extend(r);
                    }
                }
                b'\r' => {}
                _ => {
                    if self.line.len() >= super::protocol::MAX_LINE_BYTES {
                        self.line_too_long = true;
                    } else {
                        self.line.push(b);
                    }
                }
            }
        }
        out
    }

    /// Advance to `now`: a finished homing cycle answers its `ok`; finished moves start the next.
    pub fn tick(&mut self, now: f64) -> Vec<u8> {
        let mut out = Vec::new();
        if let Some(t) = self.homing_until
            && now >= t
        {
            self.homing_until = None;
            (self.x, self.y) = (0.0, 0.0);
            self.state = MachineState::Idle;
            out.extend(self.reply(Ok(())));
        }
        self.advance(now);
        out
    }

    /// Move the table along its motion to `now`.
    fn advance(&mut self, now: f64) {
        let (s, a) = (self.settings.max_speed, self.settings.accel);
        while let Some(m) = self.motion {
            if self.stalled {
                // Frozen where it stalled; the state stays Run.
                return;
            }
            let end = m.start + super::protocol::move_seconds(m.length(), m.speed, a);
            if now < end {
                [self.x, self.y] = m.at(a, now - m.start);
                self.feed = m.speed * 60.0;
                return;
            }
            [self.x, self.y] = m.to;
            self.motion = None;
            if let Some((to, speed)) = self.queue.pop_front() {
                self.motion = Some(Motion { from: [self.x, self.y], to, start: end, speed: speed.min(s) });
            } else {
                self.state = MachineState::Idle;
                self.feed = 0.0;
            }
        }
    }

    fn stop_all(&mut self) {
        self.motion = None;
        self.queue.clear();
        self.homing_until = None;
        self.stalled = false;
        self.feed = 0.0;
    }

    fn hold(&mut self, now: f64) {
        self.advance(now);
        if self.motion.is_some() {
            self.stop_all();
            self.state = MachineState::Hold;
        }
    }

    fn reset(&mut self, now: f64) -> Vec<u8> {
        self.advance(now);
        let moving = self.motion.is_some() || self.homing_until.is_some();
        self.stop_all();
        self.line.clear();
        self.drop_reply = false;
        self.error_next = None;
        let mut out = String::new();
        if moving {
            out += "ALARM:3\r\n";
        }
        out += &format!("\r\n{}\r\n", self.settings.banner);
        if moving || self.settings.homing || self.state == MachineState::Alarm {
            self.state = MachineState::Alarm;
            out += "[MSG:'$H'|'$X' to unlock]\r\n";
        } else {
            self.state = MachineState::Idle;
        }
        out.into_bytes()
    }

    fn status_line(&mut self, now: f64) -> Vec<u8> {
        self.advance(now);
        format!("<{}|MPos:{:.3},{:.3},0.000|FS:{:.0},0>\r\n", self.state.as_str(), self.x, self.y, self.feed)
            .into_bytes()
    }

    /// `ok` or `error:n`, unless a dropped reply was injected.
    fn reply(&mut self, r: Result<(), u32>) -> Vec<u8> {
        if std::mem::take(&mut self.drop_reply) {
            return Vec::new();
        }
        match r {
            Ok(()) => b"ok\r\n".to_vec(),
            Err(n) => format!("error:{n}\r\n").into_bytes(),
        }
    }

    fn execute(&mut self, line: &str, now: f64) -> Vec<u8> {
        self.advance(now);
        if let Some(n) = self.error_next.take() {
            return self.reply(Err(n));
        }
        let upper = line.to_ascii_uppercase();
        match upper.as_str() {
            "$H" => {
                if !self.settings.homing {
                    return self.reply(Err(5));
                }
                self.stop_all();
                self.state = MachineState::Home;
                self.homing_until = Some(now + self.settings.home_seconds);
                Vec::new() // `ok` when the cycle ends (tick)
            }
            "$X" => {
                let mut out = Vec::new();
                if self.state == MachineState::Alarm {
                    self.state = MachineState::Idle;
                    out.extend(b"[MSG:Caution: Unlocked]\r\n");
                }
                out.extend(self.reply(Ok(())));
                out
            }
            "$I" => {
                let mut out = b"[VER:1.1h.20190825:]\r\n[OPT:V,15,128]\r\n".to_vec();
                out.extend(self.reply(Ok(())));
                out
            }
            "$$" => {
                let mut out: Vec<u8> =
                    self.settings.listing().into_iter().flat_map(|(n, v)| setting_line(n, v).into_bytes()).collect();
                out.extend(self.reply(Ok(())));
                out
            }
            _ if upper.starts_with('$') => {
                let r = match upper[1..].split_once('=').map(|(n, v)| (n.parse::<u32>(), v.parse::<f64>())) {
                    Some((Ok(n), Ok(v))) => self.settings.set(n, v),
                    Some((Ok(_), Err(_))) => Err(2),
                    _ => Err(3),
                };
                self.reply(r)
            }
            _ => match self.gcode(&upper, now) {
                Ok(()) => self.reply(Ok(())),
                Err(n) => self.reply(Err(n)),
            },
        }
    }

    /// `G90 G1 X… F…` (or `G0`): queue the move.
    fn gcode(&mut self, line: &str, now: f64) -> Result<(), u32> {
        let (mut rapid, mut target, mut tilt, mut feed) = (false, None, None, None);
        for word in line.split_whitespace() {
            let (letter, value) = word.split_at(1);
            let v: f64 = value.parse().map_err(|_| 2u32)?;
            if !v.is_finite() {
                return Err(2);
            }
            match (letter, v) {
                ("G", 90.0) => {}
                ("G", 0.0) => rapid = true,
                ("G", 1.0) => rapid = false,
                ("X", v) => target = Some(v),
                ("Y", v) => tilt = Some(v),
                ("F", v) if v > 0.0 => feed = Some(v),
                ("F", _) => return Err(2),
                _ => return Err(20),
            }
        }
        if self.state == MachineState::Alarm {
            return Err(9);
        }
        if target.is_none() && tilt.is_none() {
            return Ok(());
        }
        // An axis not named stays where the queue leaves it.
        let last = self.queue.back().map(|q| q.0).or(self.motion.map(|m| m.to)).unwrap_or([self.x, self.y]);
        let to = [target.unwrap_or(last[0]), tilt.unwrap_or(last[1])];
        let speed = if rapid { self.settings.max_speed } else { feed.ok_or(22u32)? / 60.0 };
        let speed = speed.min(self.settings.max_speed);
        if self.motion.is_some() {
            self.queue.push_back((to, speed));
        } else {
            self.motion = Some(Motion { from: [self.x, self.y], to, start: now, speed });
            self.state = MachineState::Run;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::devices::turntable::protocol::{Reply, StatusReport};

    fn lines(b: &[u8]) -> Vec<Reply> {
        String::from_utf8_lossy(b).lines().filter_map(Reply::parse).collect()
    }

    fn status(sim: &mut GrblSim, now: f64) -> StatusReport {
        match lines(&sim.input(b"?", now)).pop() {
            Some(Reply::Status(s)) => s,
            other => panic!("no status: {other:?}"),
        }
    }

    /// A move naming Y too runs both axes along one straight path, the feed along it: X 0 → 30 and Y 0 → 40
    /// at 3000 °/min (50 °/s) over a path of 50°, with 250 °/s², takes 50/50 + 50/250 s; halfway both are
    /// halfway; the status reports Y; a move naming only Y leaves X where it is.
    #[test]
    fn a_tilting_move_runs_both_axes_along_one_path() {
        let board = SimSettings { max_speed: 100.0, accel: 250.0, ..Default::default() };
        let mut sim = GrblSim::new(board);
        sim.power_on();
        assert_eq!(lines(&sim.input(b"G90 G1 X30 Y40 F3000\n", 0.0)), [Reply::Ok]);
        let t = 1.0 + 50.0 / 250.0;
        let mid = status(&mut sim, t / 2.0);
        assert!((mid.x - 15.0).abs() < 1e-9 && (mid.y - 20.0).abs() < 1e-9, "halfway: {mid:?}");
        assert_eq!(mid.state, MachineState::Run);
        let before = status(&mut sim, t - 0.01);
        assert!(before.state == MachineState::Run && before.y < 40.0, "{before:?}");
        let end = status(&mut sim, t + 1e-6);
        assert_eq!((end.state, end.x, end.y), (MachineState::Idle, 30.0, 40.0));
        assert_eq!(lines(&sim.input(b"G90 G1 Y-10 F3000\n", 2.0)), [Reply::Ok]);
        assert_eq!(sim.tilt(10.0), -10.0);
        assert_eq!(sim.position(10.0), 30.0, "X stays");
    }

    #[test]
    fn banner_alarm_home_and_a_timed_move() {
        let board = SimSettings { homing: true, max_speed: 90.0, accel: 180.0, ..Default::default() };
        let mut sim = GrblSim::new(board);
        let boot = lines(&sim.power_on());
        assert_eq!(boot[0], Reply::Banner("1.1h".into()));
        assert_eq!(boot[1], Reply::Feedback("MSG:'$H'|'$X' to unlock".into()));
        assert_eq!(lines(&sim.input(b"G90 G1 X45 F720\n", 0.0)), [Reply::Error(9)], "locked");
        assert!(sim.input(b"$H\n", 0.0).is_empty(), "ok only when homed");
        assert_eq!(status(&mut sim, 0.5).state, MachineState::Home);
        assert_eq!(lines(&sim.tick(1.0)), [Reply::Ok]);
        // 90° at 1440 °/min = 24 °/s (below the 90 °/s top speed), 180 °/s²: 90/24 + 24/180 s.
        assert_eq!(lines(&sim.input(b"G90 G1 X90 F1440\n", 2.0)), [Reply::Ok]);
        let t = 90.0 / 24.0 + 24.0 / 180.0;
        let mid = status(&mut sim, 2.0 + t / 2.0);
        assert!(mid.state == MachineState::Run && (mid.x - 45.0).abs() < 1e-6, "{mid:?}");
        let end = status(&mut sim, 2.0 + t + 1e-9);
        assert_eq!((end.state, end.x), (MachineState::Idle, 90.0));
    }

    #[test]
    fn faults_errors_and_resets() {
        let mut sim = GrblSim::new(SimSettings { max_speed: 90.0, accel: 180.0, ..Default::default() });
        sim.power_on();
        assert_eq!(lines(&sim.input(b"G1 X10\n", 0.0)), [Reply::Error(22)], "no feed rate");
        assert_eq!(lines(&sim.input(b"M3 S1000\n", 0.0)), [Reply::Error(20)]);
        assert_eq!(lines(&sim.input(b"G1 X1e\n", 0.0)), [Reply::Error(2)]);
        assert!(lines(&sim.input(&[b'X'; 100], 0.0)).is_empty());
        assert_eq!(lines(&sim.input(b"\n", 0.0)), [Reply::Error(11)], "line too long");
        sim.inject(Fault::DropReply, 0.0);
        assert!(lines(&sim.input(b"G0 X1\n", 0.0)).is_empty(), "dropped");
        sim.inject(Fault::Error(15), 1.0);
        assert_eq!(lines(&sim.input(b"G0 X2\n", 1.0)), [Reply::Error(15)]);
        assert_eq!(lines(&sim.input(b"G0 X180\n", 1.0)), [Reply::Ok]);
        sim.inject(Fault::Stall, 1.5);
        let stalled = status(&mut sim, 1.5).x;
        let later = status(&mut sim, 60.0);
        assert_eq!((later.state, later.x), (MachineState::Run, stalled), "stalled in Run");
        let reset = lines(&sim.input(&[SOFT_RESET], 61.0));
        assert_eq!(reset[0], Reply::Alarm(3), "a reset in motion loses the position");
        assert_eq!(sim.state(), MachineState::Alarm);
        assert_eq!(lines(&sim.input(b"$X\n", 62.0)), [Reply::Feedback("MSG:Caution: Unlocked".into()), Reply::Ok]);
        assert_eq!(lines(&sim.inject(Fault::Alarm(1), 63.0)), [Reply::Alarm(1)]);
        assert_eq!(sim.state(), MachineState::Alarm);
    }

    /// A factory-fresh board: unlocked after a reset, `$H` refused (`error:5`), `$$` lists Grbl 1.1h's
    /// defaults, `$110=` changes the top rate, and moves run at the board's 500 °/min whatever `F` asks.
    #[test]
    fn a_factory_fresh_board_lists_its_settings_and_refuses_homing() {
        let mut sim = GrblSim::new(SimSettings::default());
        let boot = lines(&sim.power_on());
        assert_eq!(boot, [Reply::Banner("1.1h".into())], "no lock message without homing");
        assert_eq!(sim.state(), MachineState::Idle);
        assert_eq!(lines(&sim.input(b"$H\n", 0.0)), [Reply::Error(5)]);
        let listed = lines(&sim.input(b"$$\n", 0.0));
        let want: Vec<Reply> = FACTORY_SETTINGS.iter().map(|&(n, v)| Reply::Setting(n, v)).chain([Reply::Ok]).collect();
        assert_eq!(listed, want);
        assert_eq!(lines(&sim.input(b"$110=1000\n", 0.0)), [Reply::Ok]);
        assert_eq!(lines(&sim.input(b"$999=1\n", 0.0)), [Reply::Error(3)]);
        assert_eq!(lines(&sim.input(b"$120=-1\n", 0.0)), [Reply::Error(4)]);
        assert!(lines(&sim.input(b"$$\n", 0.0)).contains(&Reply::Setting(110, 1000.0)));
        assert_eq!(sim.eeprom().max_speed, 1000.0 / 60.0, "kept for the next power-on");
        // 90° asked at 60 °/s runs at the board's 1000 °/min (16.7 °/s) with 10 °/s².
        assert_eq!(lines(&sim.input(b"G90 G1 X90 F3600\n", 1.0)), [Reply::Ok]);
        let t = crate::devices::turntable::protocol::move_seconds(90.0, 1000.0 / 60.0, 10.0);
        assert!(status(&mut sim, 1.0 + t - 0.1).state == MachineState::Run);
        assert_eq!(status(&mut sim, 1.0 + t + 1e-9).x, 90.0);
        let fast = SimSettings::default().faster(10.0);
        assert!((fast.max_speed - 500.0 / 6.0).abs() < 1e-9 && fast.accel == 1000.0 && fast.home_seconds == 0.1);
    }
}
