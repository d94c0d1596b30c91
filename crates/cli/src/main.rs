//! `hilo`: which roadside sensors to mount where, and how well they will detect road users.

mod dataset;
mod eval;
mod progress;
mod scan;
mod stages;
mod study;
mod train;

use anyhow::{Context, Result};

/// candle allocates a fresh buffer for every tensor operation; glibc's malloc hands large ones
/// back to the kernel on free, so a training step spent about as long in page faults as in
/// arithmetic. mimalloc keeps them (for good in the commands that train: [`PURGE_DELAY`]).
#[global_allocator]
static GLOBAL: mimalloc::MiMalloc = mimalloc::MiMalloc;
use clap::{Parser, Subcommand};
use hilo_raycast::Scene;
use std::path::{Path, PathBuf};

#[derive(Parser, Debug)]
#[command(name = "hilo", version, about = "Roadside LiDAR + 4D-radar placement, simulation and detection studies")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Inspect a scene (an intersection's digital twin).
    Scene {
        #[command(subcommand)]
        command: SceneCommand,
    },
    /// Simulate one frame of one sensor on a scene with a few road users; write PCD or PLY.
    Scan(scan::ScanArgs),
    /// The end-to-end study: placement, datasets, training, evaluation, report.
    Study(study::StudyArgs),
    /// Place each configuration of a study optimally (integer programming over visibility).
    Place(stages::PlaceArgs),
    /// Check the placement objective against trained detectors over a set of placements.
    Validate(study::ValidateArgs),
    /// Simulate traffic and record a dataset (nuScenes layout) with a placement's sensors.
    Simulate(stages::SimulateArgs),
    /// Train a detector (a preset or a detector config of one's own) on a dataset's train split, on the CPU
    /// (the first GPU when hilo is built with `--features cuda`).
    Train(train::TrainArgs),
    /// Run a trained detector on a split and write a nuScenes submission.
    Detect(train::DetectArgs),
    /// nuScenes detection metrics (AP, TP errors, NDS) of a submission.
    Eval(eval::EvalArgs),
    /// Inspect a dataset in the nuScenes layout.
    Dataset {
        #[command(subcommand)]
        command: DatasetCommand,
    },
    /// Benchmarks that report speed together with the error paid for it.
    Bench {
        #[command(subcommand)]
        command: BenchCommand,
    },
}

#[derive(Subcommand, Debug)]
enum SceneCommand {
    /// Draw a top-down picture of the scene: roads, lanes, crosswalks, poles, buildings, trees, ROIs.
    Show {
        /// Scene TOML, or an OpenDRIVE road network (.xodr) with --junction or --near; the
        /// embedded default intersection when omitted.
        scene: Option<PathBuf>,
        /// Output PNG.
        #[arg(long, default_value = "scene.png")]
        out: PathBuf,
        /// Resolution, pixels per metre.
        #[arg(long, default_value_t = 4.0)]
        px_per_m: f32,
        #[command(flatten)]
        junction: JunctionArgs,
    },
    /// Print a JSON summary: triangles, objects, mounts, ROIs and their areas (and, for an
    /// OpenDRIVE junction, the defaults its import used).
    Info {
        scene: Option<PathBuf>,
        #[command(flatten)]
        junction: JunctionArgs,
    },
    /// Write one junction of an OpenDRIVE road network (.xodr) as a scene file to edit.
    Import {
        /// The OpenDRIVE file.
        file: PathBuf,
        #[command(flatten)]
        junction: JunctionArgs,
        /// The scene file to write (TOML; its header lists what the import assumed).
        #[arg(long)]
        out: PathBuf,
    },
}

/// Which junction of an OpenDRIVE road network: its id, or the one nearest a point.
#[derive(clap::Args, Debug, Default)]
pub struct JunctionArgs {
    /// The junction's `<junction id>`.
    #[arg(long, conflicts_with = "near")]
    junction: Option<String>,
    /// Or the junction whose centre is nearest this point, `x,y` in the file's frame (metres).
    #[arg(long, value_delimiter = ',', num_args = 2, allow_hyphen_values = true)]
    near: Option<Vec<f64>>,
    /// How far from --near a junction's centre may be, metres.
    #[arg(long, default_value_t = 100.0, requires = "near")]
    radius_m: f64,
}

impl JunctionArgs {
    fn pick(&self) -> Option<hilo_raycast::scene::opendrive::JunctionPick> {
        use hilo_raycast::scene::opendrive::JunctionPick;
        match (&self.junction, &self.near) {
            (Some(id), _) => Some(JunctionPick::id(id)),
            (None, Some(p)) => Some(JunctionPick { id: None, near: Some([p[0], p[1]]), radius_m: Some(self.radius_m) }),
            (None, None) => None,
        }
    }
}

#[derive(Subcommand, Debug)]
enum DatasetCommand {
    /// Frames, boxes per class and points per box; `--png` draws one frame.
    Stats(dataset::StatsArgs),
}

#[derive(Subcommand, Debug)]
enum BenchCommand {
    /// hilo's ray engine against parry3d's TriMesh (and raw obvhs) on the same LiDAR sweeps.
    Raycast {
        /// Scene TOML; the embedded default intersection when omitted.
        #[arg(long)]
        scene: Option<PathBuf>,
        /// Azimuth steps per 64-beam sweep (one sweep per mounting pole).
        #[arg(long, default_value_t = 4096)]
        azimuth_steps: usize,
        /// Timed repetitions per engine (the median is reported).
        #[arg(long, default_value_t = 5)]
        repeats: usize,
        /// Print one JSON object instead of a table.
        #[arg(long)]
        json: bool,
    },
    /// Placement at the default scale: visibility, the paper's three configurations, the
    /// budgeted problem, and the plain formulation handed to CBC on the same instance.
    Placement {
        /// Time limit for CBC (it rounds to whole seconds and may overshoot).
        #[arg(long, default_value_t = 120.0)]
        cbc_seconds: f64,
        #[arg(long)]
        json: bool,
    },
    /// Dataset generation at the paper's scale (37 scenes x 20 s x 20 Hz) for a study's first
    /// configuration (the default study's 2 x 16-beam LiDAR + radar): frames/s and MB written.
    Simulate {
        /// Study TOML; the embedded default (field sensors, the beams' width cast) when omitted.
        study: Option<PathBuf>,
        #[arg(long, default_value_t = 37)]
        scenes: usize,
        #[arg(long, default_value_t = 20.0)]
        seconds: f64,
        #[arg(long, default_value_t = 20.0)]
        rate_hz: f64,
        /// Keep the dataset in this folder (a temporary folder otherwise).
        #[arg(long)]
        keep: Option<PathBuf>,
        #[arg(long)]
        json: bool,
    },
    /// The nuScenes metric on synthetic frames (6 classes, up to 500 predictions a frame).
    Eval {
        #[arg(long, default_value_t = 3000, value_parser = clap::value_parser!(u32).range(1..=1_000_000))]
        frames: u32,
        #[arg(long, default_value_t = 500)]
        max_pred: usize,
        #[arg(long, default_value_t = 3)]
        repeats: usize,
        #[arg(long)]
        json: bool,
    },
    /// Where a training step's time goes (pillarisation, pillar net, backbone, head, loss,
    /// backward, optimizer, data) for each preset, and its GFLOP/s against the machine's
    /// matrix-product peak measured in the same run; the step's matrix products replayed alone
    /// at their sizes split that share into their own rate and their share of the step's time.
    Train {
        /// A dataset written by `hilo simulate` (its training split is used).
        #[arg(long)]
        data: PathBuf,
        /// Presets (comma-separated).
        #[arg(long, value_delimiter = ',', default_value = "centerpoint,lirafusion-like")]
        presets: Vec<String>,
        /// Timed steps per preset (after 3 warm-up steps).
        #[arg(long, default_value_t = 40)]
        steps: usize,
        /// A lever turned off or changed, for a before/after row: `layout=dense`,
        /// `background=false`, `radar_clutter=false`, `paste=true|false`, `radar_sweeps=K`, `lidar_sweeps=K`,
        /// `batch=N`, `replicas=N`, `sync_batch_norm=true|false`, `sparse_backward=gather|scatter`,
        /// `optimizer=fused|composite`, `fused=on|off|conv+bn_relu+loss`, `head_dilation=N`, `layers=N`,
        /// `blocks=[{"stride":2,"channels":32,"layers":2},...]` (repeatable).
        #[arg(long = "variant", value_parser = hilo::bench::parse_variant)]
        variants: Vec<(String, serde_json::Value)>,
        #[arg(long)]
        json: bool,
    },
    /// One frame of the paper's cheapest suite (2 x 16-beam LiDAR + radar) with moving actors,
    /// and of a 64-beam LiDAR + radar, on the default scene.
    Sensors {
        /// Moving road users in the scene.
        #[arg(long, default_value_t = 50)]
        actors: usize,
        /// Frames timed (the median is reported).
        #[arg(long, default_value_t = 40)]
        frames: usize,
        #[arg(long)]
        json: bool,
    },
}

/// Loads the named scene (or junction of a road network) or the embedded default.
pub fn load_scene(path: Option<&Path>, junction: &JunctionArgs) -> Result<Scene> {
    match path {
        Some(p) => {
            Scene::load_with(p, junction.pick().as_ref()).with_context(|| format!("loading scene {}", p.display()))
        }
        None => Scene::default_fixture().context("building the embedded default scene"),
    }
}

/// Set by [`pin_training_env`] in the process it starts: the size of rayon's global pool.
const GLOBAL_THREADS: &str = "HILO_GLOBAL_THREADS";

/// mimalloc hands memory it has not reused for a second back to the kernel, and a training
/// step then faults the pages of its next buffers in again. `-1` keeps what the process once
/// held (the same weights, sooner; docs/measurements.md); the price is a resident size that
/// stays at its peak (the frames held in memory dominate it anyway).
const PURGE_DELAY: (&str, &str) = ("MIMALLOC_PURGE_DELAY", "-1");

/// The environment candle and the allocator read once, set before they start. A running
/// process cannot set its own environment without `unsafe`, so a command that trains or
/// detects and finds a variable unset starts itself once more with it (a value the user set is
/// kept) and exits with its status:
/// - `RAYON_NUM_THREADS`: candle sizes its parallelism from it, and without it works the number
///   out again from `/proc/cpuinfo` and `/sys` on every matrix product (about 50 files opened
///   per training step). `hilo detect`: every core. candle's matrix product sizes its
///   parallelism from the variable, not from the pool it runs in, and splitting a product for
///   threads a one-thread pool does not have is slow: `hilo study` trains several detectors at
///   once, each on a one-thread pool, and `hilo train` and `hilo bench train` run a schedule's
///   data-parallel replicas each on a one-thread pool. These get
///   `RAYON_NUM_THREADS=1` (for candle) and [`GLOBAL_THREADS`] = every core (for rayon's global
///   pool: the replicas, the custom kernels of a one-replica schedule, placement and
///   simulation). Not for a single stage or a workflow file, whose engine sets its own.
/// - [`PURGE_DELAY`], for the same commands and a single study stage.
///
/// Returns `None` where nothing was started.
fn pin_training_env(cli: &Cli) -> Result<Option<std::process::ExitStatus>> {
    let cores = std::thread::available_parallelism().map_or(1, |n| n.get()).to_string();
    let threads: Vec<(&str, &str)> = match &cli.command {
        Command::Study(args) if args.stage.is_none() && args.workflow.is_none() => {
            vec![("RAYON_NUM_THREADS", "1"), (GLOBAL_THREADS, &cores)]
        }
        Command::Train(_) | Command::Validate(_) | Command::Bench { command: BenchCommand::Train { .. } } => {
            vec![("RAYON_NUM_THREADS", "1"), (GLOBAL_THREADS, &cores)]
        }
        Command::Detect(_) => vec![("RAYON_NUM_THREADS", &cores)],
        // A single stage, run by a workflow engine that sets the threads itself.
        Command::Study(args) if args.stage.is_some() => Vec::new(),
        _ => return Ok(None),
    };
    // The thread settings go together: a user's RAYON_NUM_THREADS keeps ours out.
    let mut env = if std::env::var_os("RAYON_NUM_THREADS").is_none() { threads } else { Vec::new() };
    env.push(PURGE_DELAY);
    hilo_core::machine::rerun_with(&env).context("starting hilo again with its thread and allocator settings")
}

fn main() -> Result<()> {
    let cli = Cli::parse();
    if let Some(n) = std::env::var(GLOBAL_THREADS).ok().and_then(|v| v.parse::<usize>().ok()) {
        // Explicit, so it wins over RAYON_NUM_THREADS (which is for candle here).
        rayon::ThreadPoolBuilder::new().num_threads(n).build_global().context("starting the thread pool")?;
    } else if let Some(status) = pin_training_env(&cli)? {
        std::process::exit(hilo_core::machine::exit_code(status));
    }
    match cli.command {
        Command::Scene { command: SceneCommand::Show { scene, out, px_per_m, junction } } => {
            if !out.extension().is_some_and(|e| e.eq_ignore_ascii_case("png")) {
                anyhow::bail!("--out {}: the picture is a PNG; give a file name ending in .png", out.display());
            }
            let scene = load_scene(scene.as_deref(), &junction)?;
            if !(px_per_m.is_finite() && px_per_m > 0.0 && px_per_m <= 50.0) {
                anyhow::bail!("--px-per-m must be in (0, 50], got {px_per_m}");
            }
            let png = hilo_study::render::scene_png(&scene, px_per_m)?;
            hilo_core::fs::write_atomic(&out, &png)?;
            eprintln!("wrote {} ({})", out.display(), scene.source_name());
        }
        Command::Scene { command: SceneCommand::Info { scene, junction } } => {
            let scene = load_scene(scene.as_deref(), &junction)?;
            println!("{}", serde_json::to_string_pretty(&hilo_study::render::scene_summary(&scene))?);
        }
        Command::Scene { command: SceneCommand::Import { file, junction, out } } => {
            let pick = junction.pick().context("name the junction: --junction ID, or --near X,Y")?;
            let imported = hilo_raycast::scene::opendrive::import_to(&file, &pick, &out)?;
            eprintln!("wrote {} (junction {}, {} arms)", out.display(), imported.junction, imported.config.arms.len());
            for n in &imported.notes {
                eprintln!("  {n}");
            }
        }
        Command::Scan(args) => scan::run(&args)?,
        Command::Eval(args) => eval::run(&args)?,
        Command::Simulate(args) => stages::simulate(&args)?,
        Command::Train(args) => train::run_train(&args)?,
        Command::Study(args) => {
            study::study(&args)?;
        }
        Command::Detect(args) => train::run_detect(&args)?,
        Command::Dataset { command: DatasetCommand::Stats(args) } => dataset::stats(&args)?,
        Command::Place(args) => {
            stages::place(&args)?;
        }
        Command::Validate(args) => study::validate(&args)?,
        Command::Bench { command } => bench(command)?,
    }
    Ok(())
}

/// A bench's report: one JSON line with `--json`, else its table (or indented JSON).
fn emit<R: serde::Serialize>(report: &R, json: bool, table: Option<fn(&R)>) -> Result<()> {
    match (json, table) {
        (false, Some(table)) => table(report),
        (false, None) => println!("{}", serde_json::to_string_pretty(report)?),
        (true, _) => println!("{}", serde_json::to_string(report)?),
    }
    Ok(())
}

fn bench(command: BenchCommand) -> Result<()> {
    match command {
        BenchCommand::Eval { frames, max_pred, repeats, json } => {
            emit(&hilo::bench::eval(frames as usize, max_pred, repeats.max(1))?, json, None)
        }
        BenchCommand::Simulate { study, scenes, seconds, rate_hz, keep, json } => {
            let study = stages::load_study(study.as_deref())?;
            let total = hilo::bench::simulate::config(&study, scenes, seconds, rate_hz).total_frames();
            let reporter = std::sync::Mutex::new(progress::Reporter::new());
            let report = hilo::bench::simulate::bench(&study, scenes, seconds, rate_hz, keep.as_deref(), &|done| {
                if let Ok(mut r) = reporter.lock() {
                    r.task("bench simulate", done, total, "frames");
                }
            })?;
            emit(&report, json, None)
        }
        BenchCommand::Placement { cbc_seconds, json } => emit(&hilo::bench::placement(cbc_seconds)?, json, None),
        BenchCommand::Train { data, presets, steps, variants, json } => {
            let report = hilo::bench::train(&train::registry()?, &data, &presets, steps.max(1), &variants)?;
            emit(&report, json, Some(hilo::bench::TrainReport::print_table))
        }
        BenchCommand::Sensors { actors, frames, json } => {
            emit(&hilo::bench::sensors(actors, frames.max(1))?, json, Some(hilo::bench::SensorsReport::print_table))
        }
        BenchCommand::Raycast { scene, azimuth_steps, repeats, json } => {
            let scene = load_scene(scene.as_deref(), &JunctionArgs::default())?;
            let report = hilo::bench::raycast(&scene, azimuth_steps, repeats.max(1))?;
            emit(&report, json, Some(hilo::bench::RaycastReport::print_table))
        }
    }
}
