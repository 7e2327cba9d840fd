//! Errors with stable codes, shared by every layer.
//!
//! Errors fall into three classes (after lyon): **bad input** (the caller's data is wrong: a truncated file, a
//! NaN coordinate, an index out of range), **resource limits** (the input is fine but exceeds a configured
//! budget) and **internal bugs** (an invariant of ours broke). Each error carries a stable, dotted code such as
//! `input.truncated` that scripts, the daemon's `error.json` and the D-Bus API may rely on; the message text is
//! for people and may change.

use std::fmt;
use std::path::{Path, PathBuf};

/// Result type of the library.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Which side is at fault.
#[derive(Copy, Clone, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum ErrorClass {
    /// The input data or the request is wrong; retrying with the same input fails the same way.
    BadInput,
    /// The input is acceptable but exceeds a configured limit (memory budget, size).
    Resource,
    /// A bug in scanstation: an invariant did not hold.
    Internal,
    /// The work ran to its end, but its result failed a quality gate (`quality.*`): it is not published as
    /// a success.
    Quality,
    /// A device of the rig (turntable, trigger) failed, timed out or is gone (`device.*`); the same request
    /// may succeed once the device is back.
    Device,
}

/// Stable error codes. The string form (`ErrorCode::as_str`) never changes once released.
#[derive(Copy, Clone, Debug, PartialEq, Eq, Hash)]
pub enum ErrorCode {
    /// The file does not exist or cannot be opened.
    InputNotFound,
    /// An operating-system read error other than a missing file.
    InputIo,
    /// The file is empty (or holds only whitespace/comments).
    InputEmpty,
    /// Neither the extension nor the content names a supported format.
    InputUnknownFormat,
    /// A header is malformed (PLY/OFF/PTS header, STL preamble).
    InputBadHeader,
    /// The data ends before the header's counts are satisfied.
    InputTruncated,
    /// A token is not a number of the expected type.
    InputBadNumber,
    /// A record has the wrong number of fields.
    InputBadRecord,
    /// A face refers to a vertex that does not exist.
    InputBadIndex,
    /// A face has fewer than three vertices.
    InputBadFace,
    /// A coordinate is NaN or infinite.
    InputNonFinite,
    /// A count cannot be right: more elements than the file's bytes can hold, or beyond the index range.
    InputAbsurdCount,
    /// The file holds no vertices, or a mesh was needed and the file has no faces.
    InputNoGeometry,
    /// An argument or option is out of its valid range.
    InputBadArgument,
    /// Repair could not make the mesh a closed 2-manifold; the message names the step that gave up.
    RepairFailed,
    /// Remeshing needs a closed, 2-manifold triangle mesh and got something else (run `repair` first).
    RemeshInputNotClosed,
    /// Remeshing could not produce a valid pure-quad mesh; the message names the step and the element.
    RemeshFailed,
    /// A control net for the surface stage is not a closed, oriented, pure-quad 2-manifold.
    SurfaceBadNet,
    /// The least-squares surface fit produced non-finite values or a growing residual.
    SurfaceFitDiverged,
    /// The B-rep failed our own validity check (open shell, unshared edge, edge curve off a face boundary,
    /// inward orientation); the message names the first offending element.
    BrepInvalid,
    /// An FEA spec is malformed or holds absurd values (negative modulus, ν ≥ 0.5, a zero radius, no load).
    FeaBadSpec,
    /// FEA needs a closed, consistently oriented surface (the inside of the solid must be defined).
    FeaOpenSurface,
    /// A support or load region of the FEA spec selects no part of the surface; the message names it.
    FeaEmptySelection,
    /// The FEA system is singular: no supports, or supports that cannot hold every rigid motion.
    FeaSingular,
    /// The iterative FEA solver (used when the direct factor would not fit the memory budget) did not converge.
    FeaNotConverged,
    /// The same input (by sha256) was already processed within the daemon's de-duplication window.
    InputDuplicate,
    /// The input file is larger than the configured `limits.max_input_size`.
    InputTooLarge,
    /// A point cloud has too few points to reconstruct a surface from ([`MIN_POINTS`](crate::stages::reconstruct::MIN_POINTS)).
    ReconstructTooFewPoints,
    /// A point cloud is flat or a line: it bounds no solid.
    ReconstructDegenerate,
    /// Reconstruction could not produce a closed, outward surface (no component survived, orientation).
    ReconstructFailed,
    /// The views of a scan set do not fit each other: more than half of them are off their neighbours after
    /// registration (each named).
    ReconstructViewsDisagree,
    /// A point cloud's normals include zero-length or non-finite vectors.
    InputBadNormal,
    /// The scan is several separate closed parts after repair (each at least repair's share of the area
    /// kept): the chain makes one solid of one connected surface.
    InputSeveralParts,
    /// A compressed input expands far more than any scan does ([`GZIP_BOMB_RATIO`](crate::geometry::io::GZIP_BOMB_RATIO)).
    InputDecompressionBomb,
    /// The operation would need more memory than its budget allows.
    ResourceMemoryBudget,
    /// Writing an output failed (disk full, permissions) or would overwrite an input.
    ResourceOutput,
    /// An internal invariant failed.
    InternalBug,
    /// The station daemon cannot be reached on the bus (not running, no bus, wrong bus).
    DaemonUnavailable,
    /// The station daemon refused a request; the message carries its D-Bus error name.
    DaemonRefused,
    /// The job was cancelled on request; the work stopped at a checkpoint between stages.
    Cancelled,
    /// The process stopped (crash, `kill -9`, power loss) while the job ran, and it was not resumed.
    Interrupted,
    /// A device's port cannot be opened, or its line reached end of file or failed (EIO): unplugged.
    DeviceUnplugged,
    /// A device answered as firmware the driver does not speak (the turntable's banner is not Grbl 1.1).
    DeviceWrongFirmware,
    /// A device did not answer, or a move did not finish, within its deadline.
    DeviceTimeout,
    /// The turntable's firmware raised an alarm (`ALARM:n`: a limit, a failed homing, a reset in motion).
    DeviceAlarm,
    /// The turntable's firmware refused a command (`error:n`).
    DeviceRefused,
    /// The turntable stopped away from its target.
    DevicePosition,
    /// The device's configuration asks for more than the board allows (a speed above its top rate, homing
    /// on a board without it); the board's own settings name the limit.
    DeviceConfig,
    /// The CAN controller is bus-off (or error-passive with every send refused): nothing can be sent until it
    /// restarts.
    DeviceBusOff,
    /// A CAN node stopped sending its heartbeat (N periods missed) or never started.
    DeviceLost,
    /// A CAN node reported a fault in an emergency (EMCY) message.
    DeviceEmergency,
    /// The scanner took a view and saw nothing: no points (nothing in its field of view, a black or shiny
    /// surface, an object stored inside out). Not a lost view: triggering again sees the same.
    DeviceEmptyView,
    /// Quality gate: the solid's surface crosses itself (pairs of its tessellation's triangles intersect).
    QualitySelfIntersecting,
    /// Quality gate: faces of the solid fold over (their normal turns by more than 90° inside the face).
    QualityFolded,
    /// Quality gate: the solid's volume misses the input's by more than its bound.
    QualityVolume,
    /// Quality gate: the solid's RMS distance to the input misses its bound (the tolerance, or the default
    /// accuracy goal).
    QualityRms,
    /// Quality gate: an open input's cap bulges past its rim's plane by more than the rim's own
    /// non-planarity and the accuracy goal.
    QualityCapBulge,
    /// Quality gate: a part of the scan lies farther from the solid than the far-tail bound (a tip cut short,
    /// a crease rounded off, a thin part lost), though the RMS may be within its own.
    QualityMaxDistance,
    /// The job ran past its time limit (a cluster's `--time`).
    ResourceTime,
    /// The cluster node running the job failed, again after one resubmission.
    ClusterNodeFailed,
    /// The cluster job was cancelled outside the station (`scancel` by someone else, an administrator).
    ClusterCancelled,
    /// The cluster refused the job or it ended in a way the station cannot map (sbatch failed, a boot
    /// failure, the node program crashed); the message gives the scheduler's words.
    ClusterFailed,
}

/// Every code, in declaration order (for [`ErrorCode::parse`]).
pub const ALL_CODES: [ErrorCode; 62] = {
    use ErrorCode::*;
    [
        InputNotFound,
        InputIo,
        InputEmpty,
        InputUnknownFormat,
        InputBadHeader,
        InputTruncated,
        InputBadNumber,
        InputBadRecord,
        InputBadIndex,
        InputBadFace,
        InputNonFinite,
        InputAbsurdCount,
        InputNoGeometry,
        InputBadArgument,
        RepairFailed,
        RemeshInputNotClosed,
        RemeshFailed,
        SurfaceBadNet,
        SurfaceFitDiverged,
        BrepInvalid,
        FeaBadSpec,
        FeaOpenSurface,
        FeaEmptySelection,
        FeaSingular,
        FeaNotConverged,
        InputDuplicate,
        InputTooLarge,
        InputDecompressionBomb,
        ReconstructTooFewPoints,
        ReconstructDegenerate,
        ReconstructFailed,
        ReconstructViewsDisagree,
        InputBadNormal,
        InputSeveralParts,
        ResourceMemoryBudget,
        ResourceOutput,
        InternalBug,
        DaemonUnavailable,
        DaemonRefused,
        Cancelled,
        Interrupted,
        DeviceUnplugged,
        DeviceWrongFirmware,
        DeviceTimeout,
        DeviceAlarm,
        DeviceRefused,
        DevicePosition,
        DeviceConfig,
        DeviceBusOff,
        DeviceLost,
        DeviceEmergency,
        DeviceEmptyView,
        QualitySelfIntersecting,
        QualityFolded,
        QualityVolume,
        QualityRms,
        QualityCapBulge,
        QualityMaxDistance,
        ResourceTime,
        ClusterNodeFailed,
        ClusterCancelled,
        ClusterFailed,
    ]
};

impl ErrorCode {
    /// The stable dotted code, e.g. `input.truncated`.
    pub const fn as_str(self) -> &'static str {
        match self {
            ErrorCode::InputNotFound => "input.not-found",
            ErrorCode::InputIo => "input.io",
            ErrorCode::InputEmpty => "input.empty",
            ErrorCode::InputUnknownFormat => "input.unknown-format",
            ErrorCode::InputBadHeader => "input.bad-header",
            ErrorCode::InputTruncated => "input.truncated",
            ErrorCode::InputBadNumber => "input.bad-number",
            ErrorCode::InputBadRecord => "input.bad-record",
            ErrorCode::InputBadIndex => "input.bad-index",
            ErrorCode::InputBadFace => "input.bad-face",
            ErrorCode::InputNonFinite => "input.non-finite",
            ErrorCode::InputAbsurdCount => "input.absurd-count",
            ErrorCode::InputNoGeometry => "input.no-geometry",
            ErrorCode::InputBadArgument => "input.bad-argument",
            ErrorCode::RepairFailed => "repair.failed",
            ErrorCode::RemeshInputNotClosed => "remesh.input-not-closed",
            ErrorCode::RemeshFailed => "remesh.failed",
            ErrorCode::SurfaceBadNet => "surface.bad-net",
            ErrorCode::SurfaceFitDiverged => "surface.fit-diverged",
            ErrorCode::BrepInvalid => "brep.invalid",
            ErrorCode::FeaBadSpec => "fea.bad-spec",
            ErrorCode::FeaOpenSurface => "fea.open-surface",
            ErrorCode::FeaEmptySelection => "fea.empty-selection",
            ErrorCode::FeaSingular => "fea.singular",
            ErrorCode::FeaNotConverged => "fea.not-converged",
            ErrorCode::InputDuplicate => "input.duplicate",
            ErrorCode::InputTooLarge => "input.too-large",
            ErrorCode::InputDecompressionBomb => "input.decompression-bomb",
            ErrorCode::ReconstructTooFewPoints => "reconstruct.too-few-points",
            ErrorCode::ReconstructDegenerate => "reconstruct.degenerate",
            ErrorCode::ReconstructFailed => "reconstruct.failed",
            ErrorCode::ReconstructViewsDisagree => "reconstruct.views-disagree",
            ErrorCode::InputBadNormal => "input.bad-normal",
            ErrorCode::InputSeveralParts => "input.several-parts",
            ErrorCode::ResourceMemoryBudget => "resource.memory",
            ErrorCode::ResourceOutput => "resource.output",
            ErrorCode::InternalBug => "internal.bug",
            ErrorCode::DaemonUnavailable => "daemon.unavailable",
            ErrorCode::DaemonRefused => "daemon.refused",
            ErrorCode::Cancelled => "cancelled",
            ErrorCode::Interrupted => "interrupted",
            ErrorCode::DeviceUnplugged => "device.unplugged",
            ErrorCode::DeviceWrongFirmware => "device.wrong-firmware",
            ErrorCode::DeviceTimeout => "device.timeout",
            ErrorCode::DeviceAlarm => "device.alarm",
            ErrorCode::DeviceRefused => "device.refused",
            ErrorCode::DevicePosition => "device.position",
            ErrorCode::DeviceConfig => "device.config",
            ErrorCode::DeviceBusOff => "device.bus-off",
            ErrorCode::DeviceLost => "device.lost",
            ErrorCode::DeviceEmergency => "device.emergency",
            ErrorCode::DeviceEmptyView => "device.empty-view",
            ErrorCode::QualitySelfIntersecting => "quality.self-intersecting",
            ErrorCode::QualityFolded => "quality.folded",
            ErrorCode::QualityVolume => "quality.volume",
            ErrorCode::QualityRms => "quality.rms",
            ErrorCode::QualityCapBulge => "quality.cap-bulge",
            ErrorCode::QualityMaxDistance => "quality.max-distance",
            ErrorCode::ResourceTime => "resource.time",
            ErrorCode::ClusterNodeFailed => "cluster.node-failed",
            ErrorCode::ClusterCancelled => "cluster.cancelled",
            ErrorCode::ClusterFailed => "cluster.failed",
        }
    }

    /// The code whose string form is `s` ([`ErrorCode::as_str`]).
    pub fn parse(s: &str) -> Option<ErrorCode> {
        ALL_CODES.iter().copied().find(|c| c.as_str() == s)
    }

    /// The class this code belongs to.
    pub const fn class(self) -> ErrorClass {
        match self {
            ErrorCode::ResourceMemoryBudget
            | ErrorCode::ResourceOutput
            | ErrorCode::FeaNotConverged
            | ErrorCode::InputTooLarge
            | ErrorCode::Cancelled
            | ErrorCode::Interrupted
            | ErrorCode::ResourceTime
            | ErrorCode::ClusterNodeFailed
            | ErrorCode::ClusterCancelled
            | ErrorCode::ClusterFailed
            | ErrorCode::DaemonUnavailable => ErrorClass::Resource,
            ErrorCode::InternalBug | ErrorCode::BrepInvalid => ErrorClass::Internal,
            ErrorCode::QualitySelfIntersecting
            | ErrorCode::QualityFolded
            | ErrorCode::QualityVolume
            | ErrorCode::QualityRms
            | ErrorCode::QualityCapBulge
            | ErrorCode::QualityMaxDistance => ErrorClass::Quality,
            ErrorCode::DeviceUnplugged
            | ErrorCode::DeviceWrongFirmware
            | ErrorCode::DeviceTimeout
            | ErrorCode::DeviceAlarm
            | ErrorCode::DeviceRefused
            | ErrorCode::DevicePosition
            | ErrorCode::DeviceConfig
            | ErrorCode::DeviceBusOff
            | ErrorCode::DeviceLost
            | ErrorCode::DeviceEmergency
            | ErrorCode::DeviceEmptyView => ErrorClass::Device,
            _ => ErrorClass::BadInput,
        }
    }
}

impl fmt::Display for ErrorCode {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.as_str())
    }
}

impl serde::Serialize for ErrorCode {
    fn serialize<S: serde::Serializer>(&self, s: S) -> std::result::Result<S::Ok, S::Error> {
        s.serialize_str(self.as_str())
    }
}

/// Where in a file an error was found.
#[derive(Copy, Clone, Debug, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Location {
    /// 1-based line of a text file.
    Line(u64),
    /// 0-based byte offset into the (decompressed) data of a binary file.
    Byte(u64),
}

impl fmt::Display for Location {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Location::Line(l) => write!(f, "line {l}"),
            Location::Byte(b) => write!(f, "byte {b}"),
        }
    }
}

/// A scanstation error: a stable code, the file and place it concerns, and a message for people.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Error {
    /// Stable code.
    pub code: ErrorCode,
    /// The file concerned, when there is one.
    pub file: Option<PathBuf>,
    /// Line or byte in `file`.
    pub location: Option<Location>,
    /// What went wrong, for people.
    pub message: String,
    /// What to do about it, when we know.
    pub hint: Option<String>,
}

impl std::error::Error for Error {}

impl fmt::Display for Error {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "[{}] ", self.code)?;
        if let Some(file) = &self.file {
            write!(f, "{}", file.display())?;
            if let Some(loc) = &self.location {
                write!(f, " ({loc})")?;
            }
            write!(f, ": ")?;
        } else if let Some(loc) = &self.location {
            write!(f, "{loc}: ")?;
        }
        write!(f, "{}", self.message)?;
        if let Some(h) = &self.hint {
            write!(f, " (hint: {h})")?;
        }
        Ok(())
    }
}

impl Error {
    /// A new error with a code and message, no file or location yet.
    pub fn new(code: ErrorCode, message: impl Into<String>) -> Self {
        Error { code, file: None, location: None, message: message.into(), hint: None }
    }

    /// An internal-bug error.
    pub fn internal(message: impl Into<String>) -> Self {
        Error::new(ErrorCode::InternalBug, message)
    }

    /// Attach the file (kept if one is already set).
    pub fn in_file(mut self, file: &Path) -> Self {
        if self.file.is_none() {
            self.file = Some(file.to_path_buf());
        }
        self
    }

    /// Attach a location (kept if one is already set).
    pub fn at(mut self, loc: Location) -> Self {
        if self.location.is_none() {
            self.location = Some(loc);
        }
        self
    }

    /// Attach a hint.
    pub fn with_hint(mut self, hint: impl Into<String>) -> Self {
        self.hint = Some(hint.into());
        self
    }

    /// The class of this error.
    pub fn class(&self) -> ErrorClass {
        self.code.class()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every code parses back from its string form, and no two share one.
    #[test]
    fn codes_round_trip_through_their_strings() {
        let mut seen = std::collections::HashSet::new();
        for c in ALL_CODES {
            assert_eq!(ErrorCode::parse(c.as_str()), Some(c));
            assert!(seen.insert(c.as_str()), "{c} twice");
        }
        // The list holds every variant: as many as `as_str` has arms.
        let arms = include_str!("error.rs").matches(concat!("=", "> \"")).count();
        assert_eq!(arms, ALL_CODES.len(), "as_str has {arms} arms");
        assert_eq!(ErrorCode::parse("no.such"), None);
    }
}
