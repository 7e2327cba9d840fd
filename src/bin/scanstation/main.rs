//! `scanstation` — the command-line tool: inspect, compare, repair, remesh, convert and fea on files, and the
//! D-Bus client of `scanstationd`. Thin: parsing (one argument struct per command, [`args`]), output
//! ([`print`]) and exit codes only; the work is in the library's `pipeline` layer.

/// `println!` that ends the process quietly with status 141 (128 + SIGPIPE, as shell tools do) when stdout's
/// reader has gone (`scanstation … | head`), instead of panicking.
macro_rules! outln {
    ($($t:tt)*) => {{
        use std::io::Write as _;
        if let Err(e) = writeln!(std::io::stdout(), $($t)*) {
            crate::print::stdout_failed(&e);
        }
    }};
}

mod args;
#[cfg(feature = "daemon")]
mod client;
mod print;
mod progress;
mod ranges;
#[cfg(feature = "daemon")]
mod sim;

use std::process::ExitCode;

use clap::{Parser, Subcommand};
use progress::LogProgress;
use scanstation::geometry::io::ReadOptions;
use scanstation::pipeline;

use args::*;
use print::emit;

#[derive(Parser)]
#[command(
    name = "scanstation",
    version,
    about = "3D scan to CAD solid: inspect, compare, repair, remesh, convert, fea"
)]
struct Cli {
    /// Print the report as JSON on stdout (errors too, as {"ok": false, "error": {...}}).
    #[arg(long, global = true)]
    json: bool,
    /// Memory budget for reading and measuring, e.g. 512M, 4G (16M to 1T).
    #[arg(long, global = true, default_value = "8G", value_parser = ranges::memory_budget)]
    memory_budget: u64,
    /// The most bytes an input may hold, decompressed for gzip (1K to 1T); larger: input.too-large.
    #[arg(long, global = true, default_value = "4G", value_parser = ranges::input_size)]
    max_input_size: u64,
    /// More log output on stderr (-v info, -vv debug).
    #[arg(short, long, global = true, action = clap::ArgAction::Count)]
    verbose: u8,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Counts, size and topology of a mesh or point cloud (PLY, OBJ, STL, OFF, XYZ/PTS; .gz too), or the views,
    /// points and poses of a scan set (.conf).
    Inspect(InspectArgs),
    /// Make a mesh a closed, outward-oriented 2-manifold: weld, fix non-manifold parts and orientation, drop
    /// debris, fill holes (smoothly); report each step and the distance to the input.
    Repair(RepairArgs),
    /// Field-aligned pure-quad remeshing of a closed mesh (run `repair` first): orientation and position
    /// fields, extraction, clean-up to all quads at the requested vertex count, projection onto the input.
    Remesh(RemeshArgs),
    /// A closed, outward 2-manifold mesh from a point cloud (PLY, XYZ/PTS; normals used when present, else
    /// estimated and oriented): screened Poisson on a grid, marching tetrahedra, measured against the points.
    Reconstruct(ReconstructArgs),
    /// The whole chain to a CAD solid: repair → quad remesh → fitted Catmull–Clark surface → B-spline B-rep
    /// → STEP (AP214), with a quality check, time and peak memory after every stage.
    Convert(ConvertArgs),
    /// Immersed (meshless) linear statics on a solid: a closed mesh, or a STEP file `convert` wrote (through
    /// the NAME.solid.ply it writes beside it). Writes result.json and surface.vtu into OUTPUT.
    Fea(FeaArgs),
    /// One picture of a mesh (PNG, 1024 x 768, four views and a legend): its deviation from a scan, its quad
    /// net, its faces, its FEA stress, or a scan set's coverage of it.
    Render(RenderArgs),
    /// Make a job bundle's self-contained HTML page (NAME.report.html) again from the bundle's files.
    Report(ReportArgs),
    /// The station daemon's state (D-Bus client of scanstationd).
    #[cfg(feature = "daemon")]
    Status(StatusArgs),
    /// The station's jobs: queued, running and recently finished.
    #[cfg(feature = "daemon")]
    Jobs(JobsArgs),
    /// Queue a file on the station (its absolute path is sent; files outside the inbox are copied).
    #[cfg(feature = "daemon")]
    Submit(SubmitArgs),
    /// Scan the object on the station's turntable and convert it: home, a view at every stop, fusion, the
    /// chain to a solid (D-Bus client of scanstationd).
    #[cfg(feature = "daemon")]
    Scan(ScanArgs),
    /// Cancel a job (by id or object path).
    #[cfg(feature = "daemon")]
    Cancel(CancelArgs),
    /// Tell a scan waiting for a person (the object turned over for its next pass) that it is done.
    #[cfg(feature = "daemon")]
    Continue(ContinueArgs),
    /// The cluster node's side of a station job (`[executor] kind = "slurm"`: what `sbatch` runs): convert
    /// the job in DIR (`work/<id>/.slurm`) as the station would, progress to DIR/progress.log, the outcome to
    /// DIR/result.json.
    #[cfg(feature = "daemon")]
    ClusterRun(ClusterRunArgs),
    /// Follow progress: one job until it finishes, or every job until interrupted. A progress bar on a
    /// terminal, JSON lines otherwise (or with --json).
    #[cfg(feature = "daemon")]
    Watch(WatchArgs),
    /// Two-sided surface distance of TEST to REFERENCE (meshes or clouds): RMS, mean, median, p95, max.
    Compare(CompareArgs),
    /// The rig's devices through the daemon: status, home, move DEG, fire (D-Bus client).
    #[cfg(feature = "daemon")]
    Rig(RigArgs),
    /// Simulated devices of the rig, for a desk without hardware and for tests.
    #[cfg(feature = "daemon")]
    #[command(subcommand)]
    Sim(SimCommand),
}

/// The simulators.
#[cfg(feature = "daemon")]
#[derive(Subcommand)]
enum SimCommand {
    /// A Grbl 1.1 turntable on a pty: banner, homing, timed moves, `?` reports; faults from stdin or a socket.
    Turntable(sim::SimTurntableArgs),
    /// A structured-light scanner node on CAN (an interface or `unix:PATH`): heartbeat, acknowledgements, views;
    /// faults from stdin or a socket.
    Trigger(sim::SimTriggerArgs),
    /// The whole rig in one process: the turntable, the scanner node and its range camera, which ray-casts
    /// the object on the table at the table's angle into a capture directory at every trigger.
    Rig(sim::SimRigArgs),
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    let level = match cli.verbose {
        0 => tracing::Level::WARN,
        1 => tracing::Level::INFO,
        _ => tracing::Level::DEBUG,
    };
    // Colours only on a terminal: a cluster job's output file and a piped log stay plain text.
    let ansi = std::io::IsTerminal::is_terminal(&std::io::stderr());
    tracing_subscriber::fmt().with_writer(std::io::stderr).with_ansi(ansi).with_max_level(level).init();
    let (json, budget) = (cli.json, cli.memory_budget);
    let read = ReadOptions { memory_budget: budget, max_input_size: cli.max_input_size };
    let result = match &cli.command {
        Command::Inspect(a) => pipeline::inspect_file(&a.file, &read).map(|r| emit(json, &r, print::print_inspect)),
        Command::Repair(a) => {
            pipeline::repair_file(&a.input, &a.output, &read, &a.options(budget), &LogProgress::new("repair"))
                .map(|r| emit(json, &r, print::print_repair))
        }
        Command::Remesh(a) => a.run(&read, budget).map(|r| emit(json, &r, print::print_remesh)),
        Command::Reconstruct(a) => {
            pipeline::reconstruct_file(&a.input, &a.output, &read, &a.options(budget), &LogProgress::new("reconstruct"))
                .map(|r| emit(json, &r, print::print_reconstruct))
        }
        Command::Convert(a) => match a.run(&read, budget) {
            Ok(r) => {
                emit(json, &r, print::print_convert);
                return match r.verdict() {
                    Ok(()) => ExitCode::SUCCESS,
                    Err(e) => print::report_quality_failure(&e, &r),
                };
            }
            Err(e) => Err(e),
        },
        Command::Fea(a) => {
            let opts = scanstation::stages::fea::FeaOptions { memory_budget: budget };
            let pictures = a.pictures.then_some(a.up);
            pipeline::fea::fea_file(&a.input, &a.spec, &a.output, &read, &opts, pictures, &LogProgress::new("fea"))
                .map(|r| emit(json, &r, print::print_fea))
        }
        Command::Render(a) => a
            .options(budget)
            .and_then(|o| pipeline::render::render_file(&a.mesh, &a.output, &read, &o))
            .map(|r| emit(json, &r, print::print_picture)),
        Command::Report(a) => pipeline::report_html::write_report_html(&a.bundle).map(|(path, d)| {
            let r = print::PageWritten { file: path, bytes: d.bytes, sha256: d.sha256 };
            emit(json, &r, print::print_page)
        }),
        Command::Compare(a) => pipeline::compare_files(
            &a.test,
            &a.reference,
            &read,
            &a.options(budget),
            a.error_map.as_deref(),
            &LogProgress::new("compare"),
        )
        .map(|r| emit(json, &r, print::print_compare)),
        #[cfg(feature = "daemon")]
        Command::Sim(SimCommand::Turntable(a)) => return sim::run(a),
        #[cfg(feature = "daemon")]
        Command::Sim(SimCommand::Trigger(a)) => return sim::run_trigger(a),
        #[cfg(feature = "daemon")]
        Command::Sim(SimCommand::Rig(a)) => return sim::run_rig(a),
        #[cfg(feature = "daemon")]
        Command::ClusterRun(a) => scanstation::daemon::worker::cluster_run(&a.dir).map(|()| {
            if json {
                print::print_json(&serde_json::json!({ "result": a.dir.join("result.json") }));
            }
        }),
        #[cfg(feature = "daemon")]
        Command::Status(_)
        | Command::Jobs(_)
        | Command::Submit(_)
        | Command::Scan(_)
        | Command::Cancel(_)
        | Command::Continue(_)
        | Command::Watch(_)
        | Command::Rig(_) => {
            return client::run(&cli.command, json);
        }
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => print::report_error(&e, json),
    }
}
