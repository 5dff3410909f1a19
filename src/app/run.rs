//! The library side of `dispdec decimate`: load, decimate, re-check, write (atomically), report.

use crate::decimate::{Options, State, Stats};
use crate::topology::topology_summary;
use crate::decimate::recheck::Recheck;
use crate::eval::{CpuEvaluator, Evaluator, NormalMode};
use crate::gpu::eval::{BandStats, GpuEvaluator};
use crate::maps::mapfile::{MapFile, Record, STATUS_MAPPED, STATUS_PINCHED, STATUS_UNREFERENCED};
use crate::mesh::repair::{Cleanup, Preparation};
use crate::mesh::{self, write_atomic};
use crate::maps::bake::Kind;
use crate::settings::{Flags, Settings};
use crate::Error;
use crate::app::outputs::{check_beside, check_outputs};
use std::path::PathBuf;
use std::time::Instant;

/// Everything `dispdec decimate` needs.
#[derive(Clone, Debug)]
pub struct DecimateJob {
    pub input: PathBuf,
    pub output: PathBuf,
    pub map: Option<PathBuf>,
    pub report: Option<PathBuf>,
    pub options: Options,
    /// Worker threads (None: all cores).
    pub threads: Option<usize>,
    /// Show a progress bar (only drawn when stderr is a terminal).
    pub progress: bool,
    pub backend: Backend,
    /// How `--backend auto` looks for a hardware adapter.
    pub probe: Probe,
    /// Welding and repair of the scan before it is checked.
    pub preparation: Preparation,
    /// `--repaired FILE`: the scan as decimated (welded, repaired), as OBJ.
    pub repaired: Option<PathBuf>,
}

/// How `--backend auto` asks whether a hardware GPU adapter exists.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub enum Probe {
    /// In this process: the Vulkan drivers it loads stay resident for the rest of the run
    /// (Mesa's lavapipe: ~50 MB, as much as the whole decimation of the bunny).
    #[default]
    InProcess,
    /// In a process of its own: `exe probe-gpu` (the `dispdec` binary's hidden command, which
    /// prints [`ProbeAnswer`] as JSON); this process loads a driver only when it opens the GPU.
    /// `show_stderr`: let what the loader and drivers print through (`--verbose`).
    Child { exe: PathBuf, show_stderr: bool },
}

/// What `dispdec probe-gpu` prints: the best hardware adapter's name, `None` (only software
/// adapters), or why the probe failed.
#[derive(Clone, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct ProbeAnswer {
    pub hardware: Option<String>,
    pub error: Option<String>,
}

impl ProbeAnswer {
    /// The probe in this process (the body of `dispdec probe-gpu`).
    pub fn here() -> ProbeAnswer {
        match crate::gpu::Gpu::primary_hardware_adapter() {
            Ok(hardware) => ProbeAnswer { hardware, error: None },
            Err(e) => ProbeAnswer { hardware: None, error: Some(e.to_string()) },
        }
    }
}

impl Probe {
    /// The best hardware adapter's name, `None` when there are only software ones.
    fn hardware_adapter(&self) -> Result<Option<String>, String> {
        let answer = match self {
            Probe::InProcess => ProbeAnswer::here(),
            Probe::Child { exe, show_stderr } => {
                let failed = |why: String| format!("the GPU probe ({} probe-gpu) failed: {why}", exe.display());
                let mut cmd = std::process::Command::new(exe);
                if *show_stderr {
                    cmd.arg("--verbose"); // the child then lets the loader's own lines through too
                }
                let out = cmd
                    .arg("probe-gpu")
                    .stdin(std::process::Stdio::null())
                    .stderr(if *show_stderr { std::process::Stdio::inherit() } else { std::process::Stdio::null() })
                    .output()
                    .map_err(|e| failed(e.to_string()))?;
                if !out.status.success() {
                    return Err(failed(format!("it exited with {}", out.status)));
                }
                serde_json::from_slice(&out.stdout).map_err(|e| failed(format!("its answer is not a probe answer: {e}")))?
            }
        };
        match answer.error {
            Some(e) => Err(e),
            None => Ok(answer.hardware),
        }
    }
}

/// Where batches are evaluated (`--backend`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Backend {
    Cpu,
    /// The WGSL shell kernels on a GPU adapter; failing to open one is an error.
    Gpu,
    /// A hardware GPU adapter when there is one, else the CPU (with a one-line message why).
    Auto,
}

/// Opens the GPU evaluator the backend asks for (`None`: the CPU), with a note saying what
/// `auto` chose and why (the reports carry it; the command prints it only with `--verbose`).
/// `auto` takes a hardware adapter only: on a software one (lavapipe, whose "GPU" is these same
/// CPU cores) the CPU evaluator is faster; `--backend gpu` forces any adapter.
pub fn open_backend(backend: Backend, probe: &Probe, dense: &crate::mesh::DenseData) -> Result<(Option<GpuEvaluator>, Option<String>), Error> {
    let open = || -> Result<GpuEvaluator, crate::error::GpuError> {
        let gpu = crate::gpu::Gpu::open_primary()?;
        GpuEvaluator::new(gpu, dense)
    };
    let cpu = |why: String| Ok((None, Some(format!("--backend auto: using the CPU: {why}"))));
    match backend {
        Backend::Cpu => Ok((None, None)),
        Backend::Gpu => Ok((Some(open()?), None)),
        Backend::Auto => match probe.hardware_adapter() {
            Err(e) => cpu(e),
            Ok(None) => cpu("no hardware adapter; software adapters (lavapipe) run on these same cores and are slower than the CPU evaluator (--backend gpu forces one)".into()),
            Ok(Some(_)) => match open() {
                Ok(g) => {
                    let note = format!("--backend auto: using the GPU {}", g.adapter());
                    Ok((Some(g), Some(note)))
                }
                Err(e) => cpu(e.to_string()),
            },
        },
    }
}

#[derive(Clone, Debug, serde::Serialize)]
pub struct Timings {
    pub load_s: f64,
    pub init_s: f64,
    pub decimate_s: f64,
    pub pick_s: f64,
    pub evaluate_s: f64,
    pub commit_s: f64,
    pub recheck_s: f64,
    /// The global check of the result (every dense vertex against the whole base).
    pub global_s: f64,
    pub write_s: f64,
    pub total_s: f64,
}

#[derive(Clone, Debug, serde::Serialize)]
pub struct RecheckSummary {
    pub valid: bool,
    pub unmapped: usize,
    pub flipped: usize,
    pub torn: usize,
    pub pinched: usize,
    /// (strict mode) vertices with more than one solution satisfying (4) on their 2-ring.
    pub ambiguous: usize,
    pub first_unmapped: Vec<u32>,
    /// Jump edges, largest jump, gap edges, straddling triangles (SPEC §1).
    pub checks: crate::guarantee::CheckStats,
}

/// The JSON report of SPEC §6.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Report {
    pub input: String,
    pub output: String,
    pub faces_in: usize,
    pub vertices_in: usize,
    pub faces_out: usize,
    pub vertices_out: usize,
    pub percent_decimated: f64,
    pub genus: i64,
    pub boundary_loops_in: usize,
    pub boundary_loops_out: usize,
    pub normals: NormalMode,
    pub strict: bool,
    pub max_valence: u32,
    pub batch: usize,
    /// `--near-rule` (triangles unless asked).
    pub near_rule: crate::decimate::NearRule,
    /// `--fine-loops`: every check walked positive loops again at 8 pieces an edge.
    pub fine_loops: bool,
    /// `--ring-directions`: which base vertices a collapse gave a new direction.
    pub ring_directions: crate::decimate::RingDirections,
    pub threads: usize,
    pub dmax: f64,
    pub max_abs_d: f64,
    /// Dense vertices failing condition (4) on the initial base, the scan itself (constant
    /// mode only: a vertex there sees only its own faces' normals).
    pub unmapped_at_start: usize,
    pub backend: String,
    pub adapter: String,
    /// What `--backend auto` chose and why (`null` for cpu and gpu).
    pub backend_note: Option<String>,
    /// GPU backend: how the kernels' answers fell (decided on the GPU, or in the tolerance
    /// band and decided in f64); `null` on the CPU.
    pub gpu_band: Option<BandStats>,
    /// The settings recorded in BASE.obj and BASE.map.
    pub settings: Settings,
    /// What welding and `--repair` changed, and the components decimated.
    pub input_cleanup: Cleanup,
    /// Faces of the input file (triangulated), before welding and repair.
    pub input_faces: usize,
    /// How many of its median edge lengths the scan's bounding-box diagonal spans (a scan
    /// beyond `mesh::MAX_EXTENT_IN_EDGES` is refused: a stray vertex far off).
    pub input_extent_in_edges: f64,
    /// Where the scan was moved on load, for the work (its coordinates less this; zero for a scan
    /// within `mesh::CENTRE_BEYOND_DIAGONALS` of the origin). The outputs are where the scan is.
    pub input_centre: [f64; 3],
    /// Warnings about the input (what readers skipped).
    pub warnings: Vec<String>,
    pub collapses: Stats,
    pub recheck: RecheckSummary,
    /// The global check (every dense vertex against the whole base mesh).
    pub global: crate::validate::Verdict,
    pub time: Timings,
    /// The process's peak resident memory up to the end of this run (MB, 10^6 bytes; Linux's
    /// VmHWM), `null` where the OS does not say.
    pub peak_rss_mb: Option<f64>,
}

/// A round width of at least one (`--batch`, for `decimate` and `bench` alike).
pub fn check_batch(batch: usize) -> Result<(), Error> {
    if batch == 0 {
        return Err(Error::Usage("--batch must be at least 1".into()));
    }
    Ok(())
}

/// Runs the decimation job; on success every requested output exists, on failure none does.
pub fn decimate(job: &DecimateJob) -> Result<Report, Error> {
    check_batch(job.options.batch)?;
    if let Some(d) = job.options.dmax {
        if !(d > 0.0 && d.is_finite()) {
            return Err(Error::Usage(format!("--dmax must be a positive number, got {d}")));
        }
    }
    if job.options.max_valence < 3 {
        return Err(Error::Usage("--max-valence must be at least 3".into()));
    }
    let mut outs = vec![("the base mesh", job.output.as_path())];
    outs.extend(job.map.as_deref().map(|p| ("the map", p)));
    outs.extend(job.report.as_deref().map(|p| ("the report", p)));
    outs.extend(job.repaired.as_deref().map(|p| ("the repaired scan", p)));
    check_outputs(&[&job.input], &outs)?;
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(job.threads.unwrap_or(0))
        .build()
        .map_err(|e| Error::Usage(format!("cannot start {} threads: {e}", job.threads.unwrap_or(0))))?;
    pool.install(|| decimate_in_pool(job))
}

fn decimate_in_pool(job: &DecimateJob) -> Result<Report, Error> {
    let t_start = Instant::now();
    let mut dense = mesh::load_scan(&job.input, &job.preparation)?;
    let t_loaded = Instant::now();
    let (genus, loops_in) = topology_summary(dense.positions.len(), &dense.faces);
    let mut state = State::new(&dense, &job.options);
    // From here on the scan's geometry is read from `state.dense` (copies of these arrays); the
    // mesh keeps its bookkeeping only (input numbering, clean-up counts): 5 MB less on the horse.
    dense.topology = Default::default();
    dense.positions = Vec::new();
    dense.faces = Vec::new();
    let (gpu, backend_note) = open_backend(job.backend, &job.probe, &state.dense)?;
    let t_init = Instant::now();

    let faces_in = state.dense.faces.len();
    let bar = if job.progress {
        let pb = indicatif::ProgressBar::new((faces_in.saturating_sub(job.options.target_faces.max(1))) as u64);
        pb.set_style(
            indicatif::ProgressStyle::with_template("{spinner} decimating [{bar:40}] {msg} {elapsed}")
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar())
                .progress_chars("=> "),
        );
        Some(pb)
    } else {
        None
    };
    let cpu = CpuEvaluator;
    let evaluator: &dyn Evaluator = match &gpu {
        Some(g) => g,
        None => &cpu,
    };
    let mut rounds = 0u64;
    state.run(evaluator, &job.options, |faces| {
        rounds += 1;
        if rounds % crate::app::memory::TRIM_EVERY_ROUNDS == 0 {
            crate::app::memory::trim_heap();
        }
        if let Some(pb) = &bar {
            pb.set_position((faces_in - faces) as u64);
            pb.set_message(format!("{faces} faces"));
        }
    })?;
    if let Some(pb) = &bar {
        pb.finish_and_clear();
    }
    let t_dec = Instant::now();
    state.release_queue();
    let recheck: Recheck = state.recheck();
    let t_check = Instant::now();

    let base = state.compact();
    state.release_decimation();
    crate::app::memory::trim_heap();
    // The final word: the independent global check, strict when the run was (SPEC §1).
    let mut check = crate::validate::CheckOptions::new(job.options.normals, state.dmax);
    check.strict = job.options.strict;
    check.sampling = job.options.loops;
    let (global, _) = crate::validate::validate_on(
        &state.dense,
        &crate::validate::Base { positions: base.positions.clone(), directions: base.directions.clone(), faces: base.faces.clone() },
        &check,
        gpu.as_ref().map(|g| g as &dyn crate::validate::Project),
    )?;
    let t_global = Instant::now();
    let (_, loops_out) = topology_summary(base.positions.len(), &base.faces);
    let settings = Settings {
        normals: job.options.normals,
        dmax: state.dmax,
        strict: job.options.strict,
        scan: job.input.file_name().map(|n| n.to_string_lossy().to_string()).unwrap_or_default(),
        scan_faces: state.dense.faces.len(),
        preparation: job.preparation,
        fine_loops: job.options.loops.is_fine(),
    };
    let header = format!(
        "dispdec base mesh: {} faces from {} ({} normals{})\nvn are the directions N used by the displacement map\n{}",
        base.faces.len(),
        job.input.display(),
        if job.options.normals == NormalMode::Constant { "constant" } else { "interpolated" },
        if job.options.strict { ", strict" } else { "" },
        settings.obj_line()
    );
    // Written where the scan lies: moved back by what its load moved it (exact, see `mesh::centre_for`).
    let obj = mesh::obj_with_normals(&mesh::translated(&base.positions, dense.centre), &base.directions, &base.faces, &header);
    let map_bytes = job.map.as_ref().map(|_| {
        let records = dense
            .dense_of_input
            .iter()
            .map(|&v| match v {
                u32::MAX => Record { face: u32::MAX, status: STATUS_UNREFERENCED, bary: [0.0; 3], d: 0.0 },
                v => {
                    let m = &state.assoc[v as usize];
                    Record {
                        face: base.face_map[m.face as usize],
                        status: if state.dense.pinched[v as usize] { STATUS_PINCHED } else { STATUS_MAPPED },
                        bary: m.bary.map(|b| b as f32),
                        d: m.d as f32,
                    }
                }
            })
            .collect();
        MapFile {
            base_faces: base.faces.len() as u32,
            dmax: state.dmax as f32,
            constant_normals: job.options.normals == NormalMode::Constant,
            strict: job.options.strict,
            settings: Some(settings.clone()),
            records,
        }
        .to_bytes()
    });
    let repaired_obj = job.repaired.as_ref().map(|p| {
        let text = mesh::obj_with_normals(
            &mesh::translated(&state.dense.pos, dense.centre),
            &[],
            &state.dense.faces,
            &format!("{} as decimated by dispdec ({:?})", job.input.display(), job.preparation),
        );
        mesh::maybe_gzip(p, text.into_bytes())
    });
    let faces_out = base.faces.len();
    let mut report = Report {
        input: job.input.display().to_string(),
        output: job.output.display().to_string(),
        faces_in,
        vertices_in: state.dense.pos.len(),
        faces_out,
        vertices_out: base.positions.len(),
        percent_decimated: 100.0 * (1.0 - faces_out as f64 / faces_in as f64),
        genus,
        boundary_loops_in: loops_in,
        boundary_loops_out: loops_out,
        normals: job.options.normals,
        strict: job.options.strict,
        max_valence: job.options.max_valence,
        batch: job.options.batch,
        near_rule: job.options.near,
        fine_loops: job.options.loops.is_fine(),
        ring_directions: job.options.ring,
        threads: rayon::current_num_threads(),
        dmax: state.dmax,
        max_abs_d: recheck.max_abs_d,
        unmapped_at_start: state.unmapped_at_start,
        backend: if gpu.is_some() { "gpu".into() } else { "cpu".into() },
        adapter: evaluator.name(),
        backend_note,
        gpu_band: gpu.as_ref().map(|g| g.stats()),
        settings,
        input_cleanup: dense.cleanup.clone(),
        input_faces: dense.input_face_count,
        input_extent_in_edges: dense.extent_in_edges,
        input_centre: dense.centre.to_array(),
        warnings: dense.warnings.clone(),
        collapses: state.stats.clone(),
        recheck: RecheckSummary {
            valid: recheck.ok(),
            unmapped: recheck.unmapped.len(),
            flipped: recheck.flipped.len(),
            torn: recheck.torn.len(),
            pinched: recheck.pinched,
            ambiguous: recheck.ambiguous,
            first_unmapped: recheck.unmapped.iter().take(10).map(|&v| dense.input_index[v as usize]).collect(),
            checks: recheck.checks.clone(),
        },
        global,
        time: Timings {
            load_s: (t_loaded - t_start).as_secs_f64(),
            init_s: (t_init - t_loaded).as_secs_f64(),
            decimate_s: (t_dec - t_init).as_secs_f64(),
            pick_s: state.stats.time_pick_s,
            evaluate_s: state.stats.time_evaluate_s,
            commit_s: state.stats.time_commit_s,
            recheck_s: (t_check - t_dec).as_secs_f64(),
            global_s: (t_global - t_check).as_secs_f64(),
            write_s: 0.0,
            total_s: 0.0,
        },
        peak_rss_mb: None,
    };
    // Write everything only now, each atomically; a failure removes what this run wrote. The
    // report goes last: it carries the time the other writes took.
    let t_w = Instant::now();
    let mut files: Vec<(&std::path::Path, &[u8])> = vec![(job.output.as_path(), obj.as_bytes())];
    if let (Some(p), Some(b)) = (&job.map, &map_bytes) {
        files.push((p.as_path(), b));
    }
    if let (Some(p), Some(b)) = (&job.repaired, &repaired_obj) {
        files.push((p.as_path(), b));
    }
    mesh::write_all_atomic(&files)?;
    report.time.write_s = t_w.elapsed().as_secs_f64();
    report.time.total_s = t_start.elapsed().as_secs_f64();
    report.peak_rss_mb = crate::app::memory::peak_rss_mb();
    if let Some(p) = &job.report {
        let json = serde_json::to_string_pretty(&report).expect("report serialises");
        if let Err(e) = write_atomic(p, json.as_bytes()) {
            for (q, _) in &files {
                let _ = std::fs::remove_file(q);
            }
            return Err(e);
        }
    }
    Ok(report)
}

// ---------------------------------------------------------------------------------------------
// dispdec validate

/// Everything `dispdec validate` needs.
#[derive(Clone, Debug)]
pub struct ValidateJob {
    pub high: PathBuf,
    pub base: PathBuf,
    pub json: Option<PathBuf>,
    pub fold_image: Option<PathBuf>,
    /// Where to write the failing dense triangles as an OBJ (`--failures`).
    pub failures: Option<PathBuf>,
    /// Atlas size in texels (the fold image and the per-face coverage).
    pub resolution: u32,
    /// Mode, dmax, strictness and preparation: each from its flag, else from BASE's settings.
    pub flags: Flags,
    pub threads: Option<usize>,
    pub backend: Backend,
    /// How `--backend auto` looks for a hardware adapter.
    pub probe: Probe,
    /// Brute force: every dense point against every base triangle (cross-checks the fast path).
    pub exhaustive: bool,
    /// Every positive image loop walked again at 8 and 64 pieces an edge (`--fine-loops`).
    pub fine_loops: bool,
}

/// One failing element, by its index in the input file and its position.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Failure {
    pub kind: &'static str,
    pub index: u32,
    pub position: [f64; 3],
}

#[derive(Clone, Debug, serde::Serialize)]
pub struct CoverageSummary {
    pub resolution: u32,
    /// Per base face, the mean number of times the scan covers it (1 = exactly once).
    pub per_face: Vec<f64>,
    pub min: f64,
    pub max: f64,
    pub folded_texels: usize,
    pub hole_texels: usize,
    pub faces_with_folds: usize,
    pub faces_with_holes: usize,
}

#[derive(Clone, Debug, serde::Serialize)]
pub struct ValidateReport {
    pub high: String,
    pub base: String,
    pub dense_faces: usize,
    pub base_faces: usize,
    /// "file" when BASE.obj gave one vn per vertex, else "computed" (the README's rule).
    pub directions: &'static str,
    /// `null` for a manifold base, else why it is not one (it is judged all the same).
    pub non_manifold: Option<String>,
    pub normals: NormalMode,
    pub strict: bool,
    /// The settings BASE.obj records (`null` for a base dispdec did not write).
    pub base_settings: Option<Settings>,
    /// What welding and repair of HIGH changed (the preparation BASE was made with, unless a
    /// flag overrode it).
    pub input_cleanup: Cleanup,
    pub backend: String,
    pub backend_note: Option<String>,
    /// GPU backend: how the projection's answers fell; `null` on the CPU.
    pub gpu_band: Option<BandStats>,
    pub verdict: crate::validate::Verdict,
    pub first_failures: Vec<Failure>,
    pub coverage: CoverageSummary,
    /// Flags that contradict BASE's settings, a scan other than BASE's, what the readers
    /// skipped, a base that is not a manifold or has no directions.
    pub warnings: Vec<String>,
    pub time_s: f64,
}

fn check_dmax(dmax: Option<f64>) -> Result<(), Error> {
    match dmax {
        Some(d) if !(d > 0.0 && d.is_finite()) => Err(Error::Usage(format!("--dmax must be a positive number, got {d}"))),
        _ => Ok(()),
    }
}

fn check_resolution(resolution: u32) -> Result<(), Error> {
    if !(16..=16384).contains(&resolution) {
        return Err(Error::Usage(format!("--resolution must be between 16 and 16384, got {resolution}")));
    }
    Ok(())
}

/// Judges BASE against HIGH from scratch; writes the JSON report and the fold image if asked.
pub fn validate(job: &ValidateJob) -> Result<ValidateReport, Error> {
    check_dmax(job.flags.dmax)?;
    check_resolution(job.resolution)?;
    let mut outs = Vec::new();
    outs.extend(job.json.as_deref().map(|p| ("the report", p)));
    outs.extend(job.fold_image.as_deref().map(|p| ("the fold image", p)));
    outs.extend(job.failures.as_deref().map(|p| ("the failures mesh", p)));
    check_outputs(&[&job.high, &job.base], &outs)?;
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(job.threads.unwrap_or(0))
        .build()
        .map_err(|e| Error::Usage(format!("cannot start threads: {e}")))?;
    pool.install(|| validate_in_pool(job))
}

/// A base, the scan it is judged against, and what to judge them with: the flags resolved
/// against the base's settings, with every warning on the way.
struct Pair {
    base: LoadedBaseMesh,
    high: mesh::DenseMesh,
    normals: NormalMode,
    dmax: f64,
    strict: bool,
    warnings: Vec<String>,
}

fn load_pair(high_path: &std::path::Path, base_path: &std::path::Path, flags: &Flags) -> Result<Pair, Error> {
    let base = load_base_with_directions(base_path)?;
    let base_name = base_path.display().to_string();
    let r = crate::settings::resolve(flags, base.settings.as_ref(), &base_name);
    let high = mesh::load_scan(high_path, &r.preparation)?;
    // Judged in the scan's frame: the base moved as the scan was on load (exactly, for a base
    // dispdec made from this scan: see `mesh::on_world_grid`).
    let mut base = base;
    mesh::translate(&mut base.base.positions, -high.centre);
    let mut warnings = base.warnings.clone();
    warnings.extend(r.warnings);
    warnings.extend(high.warnings.iter().cloned());
    warnings.extend(crate::settings::scan_mismatch(base.settings.as_ref(), &base_name, &high_path.display().to_string(), high.faces.len()));
    let dmax = r.dmax.unwrap_or_else(|| crate::decimate::DEFAULT_DMAX_FRACTION * mesh::bbox_diagonal(high.positions.iter().copied()));
    Ok(Pair { base, high, normals: r.normals, dmax, strict: r.strict, warnings })
}

fn validate_in_pool(job: &ValidateJob) -> Result<ValidateReport, Error> {
    let t0 = Instant::now();
    let Pair { base: loaded, high, normals, dmax, strict, warnings } = load_pair(&job.high, &job.base, &job.flags)?;
    let b = &loaded.base;
    let dense = mesh::DenseData::new(&high.positions, &high.faces);
    let (gpu, backend_note) = open_backend(job.backend, &job.probe, &dense)?;
    let check = crate::validate::CheckOptions {
        mode: normals,
        dmax,
        strict,
        second: true,
        exhaustive: job.exhaustive,
        compare_chords: true,
        // `--fine-loops`, or a base made with it: judged as it was made.
        sampling: crate::guarantee::LoopSampling::fine_if(job.fine_loops || loaded.settings.as_ref().is_some_and(|s| s.fine_loops)),
    };
    let (verdict, maps) = crate::validate::validate_on(&dense, b, &check, gpu.as_ref().map(|g| g as &dyn crate::validate::Project))?;
    let fold = crate::maps::fold::fold_image(&dense, b, &maps, normals, dmax, job.resolution);
    let per_face = fold.coverage();
    let coverage = CoverageSummary {
        resolution: fold.atlas.size,
        min: per_face.iter().copied().fold(f64::INFINITY, f64::min),
        max: per_face.iter().copied().fold(0.0, f64::max),
        folded_texels: fold.folded_texels(),
        hole_texels: fold.hole_texels(),
        faces_with_folds: fold.per_face.iter().filter(|p| p[2] > 0).count(),
        faces_with_holes: fold.per_face.iter().filter(|p| p[3] > 0).count(),
        per_face,
    };
    let mut first_failures = Vec::new();
    let pos = |p: glam::DVec3| (p + high.centre).to_array();
    for &v in &verdict.first_unmapped {
        first_failures.push(Failure { kind: "unmapped", index: high.input_index[v as usize], position: pos(high.positions[v as usize]) });
    }
    for (kind, list) in [("flipped", &verdict.first_flipped), ("torn", &verdict.first_torn)] {
        for &f in list.iter() {
            let t = high.faces[f as usize];
            let c = (high.positions[t[0] as usize] + high.positions[t[1] as usize] + high.positions[t[2] as usize]) / 3.0;
            first_failures.push(Failure { kind, index: f, position: pos(c) });
        }
    }
    let report = ValidateReport {
        high: job.high.display().to_string(),
        base: job.base.display().to_string(),
        dense_faces: high.faces.len(),
        base_faces: b.faces.len(),
        directions: if loaded.directions_from_file { "file" } else { "computed" },
        non_manifold: loaded.manifold.clone().err(),
        normals,
        strict,
        base_settings: loaded.settings.clone(),
        input_cleanup: high.cleanup.clone(),
        backend: match &gpu {
            Some(g) => format!("gpu: {}", g.adapter()),
            None => format!("cpu ({} threads)", rayon::current_num_threads()),
        },
        backend_note,
        gpu_band: gpu.as_ref().map(|g| g.stats()),
        verdict,
        first_failures,
        coverage,
        warnings,
        time_s: t0.elapsed().as_secs_f64(),
    };
    let mut files: Vec<(&std::path::Path, Vec<u8>)> = Vec::new();
    if let Some(p) = &job.fold_image {
        files.push((p, fold.to_png()));
    }
    if let Some(p) = &job.failures {
        files.push((p, mesh::maybe_gzip(p, failures_obj(&report, &high).into_bytes())));
    }
    if let Some(p) = &job.json {
        files.push((p, serde_json::to_string_pretty(&report).expect("report serialises").into_bytes()));
    }
    mesh::write_all_atomic(&files.iter().map(|(p, b)| (*p, b.as_slice())).collect::<Vec<_>>())?;
    Ok(report)
}

/// `validate --failures`: the scan's failing triangles as an OBJ in its own coordinates, one
/// object per kind — `flipped`, `torn` (with `--fine-loops`, those only the finer walk finds
/// too), `unmapped` (every triangle with an unmapped corner) — to open over the scan and see
/// where BASE fails. A valid base gives a file with its header only.
fn failures_obj(report: &ValidateReport, high: &mesh::DenseMesh) -> String {
    let v = &report.verdict;
    let mut is_unmapped = vec![false; high.positions.len()];
    for &u in &v.failing.unmapped {
        is_unmapped[u as usize] = true;
    }
    let around_unmapped: Vec<u32> =
        (0..high.faces.len() as u32).filter(|&f| high.faces[f as usize].iter().any(|&u| is_unmapped[u as usize])).collect();
    let header = format!(
        "dispdec validate: the triangles of {} where {} fails ({})\n{} flipped, {} torn, {} around {} unmapped vertices; one object per kind, in the scan's coordinates",
        report.high,
        report.base,
        if v.valid { "VALID: none" } else { "INVALID" },
        v.failing.flipped.len(),
        v.failing.torn.len(),
        around_unmapped.len(),
        v.failing.unmapped.len(),
    );
    mesh::obj_groups(
        &high.world_positions(),
        &high.faces,
        &[("flipped", &v.failing.flipped), ("torn", &v.failing.torn), ("unmapped", &around_unmapped)],
        &header,
    )
}

// ---------------------------------------------------------------------------------------------
// dispdec bake / reconstruct

/// A base mesh as the commands that judge or use it load it.
pub struct LoadedBaseMesh {
    pub base: crate::validate::Base,
    /// Whether the directions are the file's `vn` (else the README's rule computed them).
    pub directions_from_file: bool,
    /// The manifold check's verdict (a non-manifold base is judged all the same).
    pub manifold: Result<(), String>,
    /// The settings it records (`None` for a base dispdec did not write).
    pub settings: Option<Settings>,
    /// No directions, not a manifold, unreadable settings.
    pub warnings: Vec<String>,
}

/// Loads a base mesh with its directions (`vn`, else the README's rule) and its settings.
pub fn load_base_with_directions(path: &std::path::Path) -> Result<LoadedBaseMesh, Error> {
    let base = mesh::load_base(path)?;
    let mut warnings = Vec::new();
    let settings = base.settings.as_deref().and_then(|t| match Settings::parse(t) {
        Ok(s) => Some(s),
        Err(e) => {
            warnings.push(format!("{}: {e}; judged without its settings", path.display()));
            None
        }
    });
    if let Err(why) = &base.manifold {
        warnings.push(format!("{}: not a manifold ({why}); judged all the same", path.display()));
    }
    let from_file = base.normals.len() == base.positions.len();
    let directions = if from_file {
        base.normals
    } else {
        warnings.push(format!("{}: no vn per vertex; using computed directions (area-weighted, README rule)", path.display()));
        let (start, vf) = mesh::vertex_faces(base.positions.len(), &base.faces);
        (0..base.positions.len())
            .map(|v| {
                let cross: Vec<glam::DVec3> = vf[start[v] as usize..start[v + 1] as usize]
                    .iter()
                    .map(|&f| {
                        let t = base.faces[f as usize].map(|w| base.positions[w as usize]);
                        crate::geometry::face_cross(t[0], t[1], t[2])
                    })
                    .collect();
                crate::geometry::vertex_direction(&cross)
            })
            .collect()
    };
    Ok(LoadedBaseMesh {
        base: crate::validate::Base { positions: base.positions, directions, faces: base.faces },
        directions_from_file: from_file,
        manifold: base.manifold,
        settings,
        warnings,
    })
}

/// Agreement of a baked map with the decimator's per-vertex d (BASE.map): the map sampled at
/// each mapped dense vertex's face and barycentrics, against that vertex's d.
#[derive(Clone, Debug, serde::Serialize)]
pub struct MapAgreement {
    pub vertices: usize,
    /// Vertices whose point of the base has no d in the map (a hole of the scan there).
    pub missing: usize,
    pub rms: f64,
    pub max: f64,
}

/// Everything `dispdec bake` needs.
#[derive(Clone, Debug)]
pub struct BakeJob {
    pub high: PathBuf,
    pub base: PathBuf,
    /// The decimator's BASE.map: report how closely the baked map reproduces its d.
    pub map: Option<PathBuf>,
    pub output: PathBuf,
    pub resolution: u32,
    pub kind: Kind,
    pub flags: Flags,
}

/// What `dispdec bake` did.
#[derive(Clone, Debug)]
pub struct BakeReport {
    /// Texels that carry d, of all texels of the atlas.
    pub defined: usize,
    pub texels: usize,
    pub seconds: f64,
    pub normals: NormalMode,
    pub dmax: f64,
    pub kind: Kind,
    /// The base mesh with the map's UVs, written beside the map.
    pub uv_mesh: PathBuf,
    /// The check of the pair the map was baked from (a map of an invalid base folds or has
    /// holes where the base does).
    pub verdict: crate::validate::Verdict,
    /// How many texels came from the covering dense triangle, from a gap fill, or have no d.
    pub sources: crate::maps::bake::BakeSources,
    pub agreement: Option<MapAgreement>,
    pub warnings: Vec<String>,
}

/// The first line of the OBJ that `bake` writes beside a map, up to the map's name: a file
/// there that starts otherwise is not replaced ([`check_beside`]).
const BAKED_OBJ_MARK: &str = "# dispdec base mesh with the UVs of ";

/// `dispdec bake HIGH BASE.obj [--map BASE.map] -o DISP.(exr|pfm|png) [--kind K]`: the map, its
/// JSON sidecar, and DISP.obj (the base with one `vt` per face corner).
pub fn bake(job: &BakeJob) -> Result<BakeReport, Error> {
    let t0 = Instant::now();
    let out = &job.output;
    let ext = out.extension().map(|e| e.to_string_lossy().to_ascii_lowercase()).unwrap_or_default();
    if !["png", "pfm", "exr"].contains(&ext.as_str()) {
        return Err(Error::Usage(format!("{}: the displacement map is written as .exr or .pfm (32-bit float) or .png (16-bit + .png.json)", out.display())));
    }
    if ext == "png" && job.kind == Kind::Vector {
        return Err(Error::Usage(format!("{}: a vector map has three channels; write it as .exr or .pfm", out.display())));
    }
    check_resolution(job.resolution)?;
    check_dmax(job.flags.dmax)?;
    // DISP.obj goes beside the map: named after the base, it would replace it (say how not to).
    let uv_mesh = out.with_extension("obj");
    let mut inputs = vec![job.high.as_path(), job.base.as_path()];
    inputs.extend(job.map.as_deref());
    if let Err(Error::Usage(_)) = check_outputs(&inputs, &[("the base with the map's UVs", &uv_mesh)]) {
        return Err(Error::Usage(format!(
            "{}: the base with the map's UVs goes to {}, which is an input; name the map otherwise (e.g. {})",
            out.display(),
            uv_mesh.display(),
            out.with_file_name(format!("{}-disp.{ext}", out.file_stem().map(|s| s.to_string_lossy().to_string()).unwrap_or_default())).display()
        )));
    }
    let side_path = crate::maps::bake::sidecar_path(out);
    check_outputs(&inputs, &[("the map's sidecar", &side_path), ("the base with the map's UVs", &uv_mesh), ("the displacement map", out)])?;
    // The two files written beside the map replace only what an earlier bake wrote there.
    check_beside(&uv_mesh, "the base with the map's UVs", out, |head| head.starts_with(BAKED_OBJ_MARK.as_bytes()))?;
    check_beside(&side_path, "the map's sidecar", out, |head| {
        let text = String::from_utf8_lossy(head);
        text.trim_start().starts_with('{') && text.contains("\"convention\"")
    })?;
    let Pair { base: loaded, high: scan, normals, dmax, warnings, .. } = load_pair(&job.high, &job.base, &job.flags)?;
    let b = &loaded.base;
    let dense = mesh::DenseData::new(&scan.positions, &scan.faces);
    let per_vertex = match &job.map {
        Some(p) => {
            let m = crate::maps::mapfile::MapFile::read(p)?;
            if m.base_faces as usize != b.faces.len() {
                return Err(Error::Input {
                    path: p.display().to_string(),
                    msg: format!("a map for a {}-face base, but {} has {} faces", m.base_faces, job.base.display(), b.faces.len()),
                });
            }
            Some(m)
        }
        None => None,
    };
    // The primaries of the whole scan over the whole base: the map inverts exactly these.
    let (verdict, maps) = crate::validate::validate_on(&dense, b, &crate::validate::CheckOptions::new(normals, dmax), None)?;
    let (map, sources) = crate::maps::bake::bake(&dense, &scan.topology, b, &maps, normals, dmax, job.resolution);
    let agreement = per_vertex.map(|m| {
        let mut diffs = Vec::new();
        let mut missing = 0;
        for r in m.records.iter().filter(|r| r.status == crate::maps::mapfile::STATUS_MAPPED) {
            match map.sample(r.face, r.bary[1] as f64, r.bary[2] as f64) {
                Some(d) => diffs.push((d - r.d as f64).abs()),
                None => missing += 1,
            }
        }
        let rms = (diffs.iter().map(|x| x * x).sum::<f64>() / diffs.len().max(1) as f64).sqrt();
        MapAgreement { vertices: diffs.len() + missing, missing, rms, max: diffs.iter().copied().fold(0.0, f64::max) }
    });
    let (bytes, side) = match ext.as_str() {
        "pfm" => (map.to_pfm(job.kind), map.sidecar(job.kind)),
        "exr" => (map.to_exr(job.kind, dmax).map_err(|e| Error::Output { path: out.display().to_string(), msg: e })?, map.sidecar(job.kind)),
        _ => map.to_png16(job.kind),
    };
    let header = format!(
        "{BAKED_OBJ_MARK}{} ({} map, {} texels a side; vt: u right, v up)\n{}",
        out.file_name().map(|n| n.to_string_lossy().to_string()).unwrap_or_default(),
        job.kind.name(),
        map.atlas.size,
        loaded.settings.as_ref().map(|s| s.obj_line()).unwrap_or_default()
    );
    let obj = mesh::obj_with_uvs(&mesh::translated(&b.positions, scan.centre), &b.directions, &b.faces, |f, k| map.atlas.uv_up(f, k), &header);
    let side_json = serde_json::to_string_pretty(&side).expect("sidecar");
    mesh::write_all_atomic(&[
        (side_path.as_path(), side_json.as_bytes()),
        (uv_mesh.as_path(), obj.as_bytes()),
        (out.as_path(), &bytes),
    ])?;
    Ok(BakeReport {
        defined: map.defined(),
        texels: map.d.len(),
        seconds: t0.elapsed().as_secs_f64(),
        normals,
        dmax,
        kind: job.kind,
        uv_mesh,
        verdict,
        sources,
        agreement,
        warnings,
    })
}

/// `dispdec reconstruct BASE.obj DISP --levels L -o OUT.obj [--compare HIGH]`: writes the mesh
/// at level L and returns the distances of levels 0..=L when comparing, and the warnings. The
/// normal mode is BASE's (its settings), unless `normals` overrides it.
pub fn reconstruct(
    base: &std::path::Path,
    disp: &std::path::Path,
    levels: u32,
    out: &std::path::Path,
    compare: Option<&std::path::Path>,
    plot: Option<&std::path::Path>,
    normals: Option<NormalMode>,
) -> Result<(Vec<crate::maps::reconstruct::Distances>, Vec<String>), Error> {
    if plot.is_some() && compare.is_none() {
        return Err(Error::Usage("--plot needs --compare HIGH".into()));
    }
    if levels > 6 {
        return Err(Error::Usage(format!("--levels must be 0 to 6, got {levels}")));
    }
    let side = crate::maps::bake::sidecar_path(disp);
    let mut inputs = vec![base, disp, side.as_path()];
    inputs.extend(compare);
    let mut outs = vec![("the rebuilt mesh", out)];
    outs.extend(plot.map(|p| ("the error plot", p)));
    check_outputs(&inputs, &outs)?;
    let loaded = load_base_with_directions(base)?;
    let flags = Flags { normals, ..Default::default() };
    let r = crate::settings::resolve(&flags, loaded.settings.as_ref(), &base.display().to_string());
    let mut warnings = loaded.warnings.clone();
    warnings.extend(r.warnings);
    let b = &loaded.base;
    let map = crate::maps::bake::DispMap::read(disp, b.faces.len())?;
    // The scan where it lies (the rebuilt mesh is in the base's coordinates), once for every level.
    let scan = match compare {
        Some(p) => {
            let s = mesh::load_scan(p, &r.preparation)?;
            Some((s.world_positions(), s.faces))
        }
        None => None,
    };
    let mut table = Vec::new();
    let mut last = None;
    for level in 0..=levels {
        if scan.is_none() && level < levels {
            continue;
        }
        let rebuilt = crate::maps::reconstruct::reconstruct(b, &map, level, r.normals);
        if let Some((pos, faces)) = &scan {
            table.push(crate::maps::reconstruct::compare(&rebuilt, level, pos, faces));
        }
        last = Some(rebuilt);
    }
    let rebuilt = last.expect("at least one level");
    let header = format!("dispdec reconstruct: {} at level {levels}, {} faces", base.display(), rebuilt.faces.len());
    write_atomic(out, mesh::obj_with_normals(&rebuilt.positions, &[], &rebuilt.faces, &header).as_bytes())?;
    if let Some(p) = plot {
        if let Err(e) = write_atomic(p, &crate::maps::plot::error_plot(&table)) {
            let _ = std::fs::remove_file(out);
            return Err(e);
        }
    }
    Ok((table, warnings))
}

// ---------------------------------------------------------------------------------------------
// dispdec export

/// `dispdec export BASE.obj DISP -o OUT.glb [--levels L]`: the binary glTF of the base (its
/// settings give the normal mode) with the scalar map DISP and, with `levels`, the mesh rebuilt
/// at that level.
pub fn export(base: &std::path::Path, disp: &std::path::Path, out: &std::path::Path, levels: Option<u32>) -> Result<(crate::maps::export::Exported, Vec<String>), Error> {
    if out.extension().map(|e| e.to_string_lossy().to_ascii_lowercase()) != Some("glb".into()) {
        return Err(Error::Usage(format!("{}: export writes binary glTF (.glb)", out.display())));
    }
    if levels.is_some_and(|l| l > 6) {
        return Err(Error::Usage(format!("--levels must be 0 to 6, got {}", levels.unwrap_or(0))));
    }
    check_outputs(&[base, disp, crate::maps::bake::sidecar_path(disp).as_path()], &[("the glTF", out)])?;
    let loaded = load_base_with_directions(base)?;
    let r = crate::settings::resolve(&Flags::default(), loaded.settings.as_ref(), &base.display().to_string());
    let b = &loaded.base;
    let map = crate::maps::bake::DispMap::read(disp, b.faces.len())?;
    let rebuilt = levels.map(|l| (l, crate::maps::reconstruct::reconstruct(b, &map, l, r.normals)));
    let (bytes, info) = crate::maps::export::export_glb(b, r.normals, &map, rebuilt.as_ref().map(|(l, m)| (*l, m)));
    write_atomic(out, &bytes)?;
    Ok((info, loaded.warnings))
}

// ---------------------------------------------------------------------------------------------
// dispdec render

/// `dispdec render MESH... -o VIEW.png`: returns the adapter used.
/// Renders the meshes side by side into `out`; `mark`'s triangles (`validate --failures`' OBJ)
/// in red over the first.
pub fn render(meshes: &[PathBuf], mark: Option<&std::path::Path>, out: &std::path::Path, view: crate::gpu::render::View) -> Result<String, Error> {
    if meshes.is_empty() {
        return Err(Error::Usage("render needs at least one mesh".into()));
    }
    if !(16..=4096).contains(&view.size) {
        return Err(Error::Usage(format!("--size must be between 16 and 4096, got {}", view.size)));
    }
    let mut inputs: Vec<&std::path::Path> = meshes.iter().map(PathBuf::as_path).collect();
    inputs.extend(mark);
    check_outputs(&inputs, &[("the picture", out)])?;
    let mut loaded = Vec::new();
    for p in meshes {
        if p.extension().is_some_and(|e| e.eq_ignore_ascii_case("glb")) {
            // A binary glTF: each of its meshes, side by side.
            let bytes = std::fs::read(p).map_err(|e| Error::Input { path: p.display().to_string(), msg: format!("cannot read file: {e}") })?;
            loaded.extend(crate::maps::export::read_glb_meshes(&bytes).map_err(|msg| Error::Input { path: p.display().to_string(), msg })?);
        } else {
            let b = mesh::load_base(p)?;
            loaded.push((b.positions, b.faces));
        }
    }
    // (A valid base's failures, a header alone, mark nothing.)
    let marks = match mark {
        Some(p) => {
            let m = mesh::load_raw(p)?;
            Some((m.positions, m.faces))
        }
        None => None,
    };
    let gpu = crate::gpu::Gpu::open_primary()?;
    let (w, h, rgba) = crate::gpu::render::render(&gpu, &loaded, marks.as_ref(), &view)?;
    write_atomic(out, &crate::gpu::render::png_rgba(w, h, &rgba))?;
    Ok(gpu.describe())
}

#[cfg(all(test, unix))]
mod tests {
    use super::*;

    #[test]
    fn a_probe_that_cannot_answer_leaves_auto_on_the_cpu_saying_why() {
        // A probe process that is missing, fails, or prints something else is no hardware
        // adapter: `--backend auto` goes on with the CPU and its note says what went wrong
        // (before the probe left the process, a driver that crashed took dispdec with it).
        let dense = crate::mesh::DenseData::new(&[], &[]);
        for (exe, why) in [("/nonexistent/dispdec", "failed"), ("/bin/false", "exited with"), ("/bin/echo", "not a probe answer")] {
            let probe = Probe::Child { exe: PathBuf::from(exe), show_stderr: false };
            let e = probe.hardware_adapter().unwrap_err();
            assert!(e.contains("GPU probe") && e.contains(why), "{exe}: {e}");
            let (gpu, note) = open_backend(Backend::Auto, &probe, &dense).unwrap();
            assert!(gpu.is_none(), "{exe}");
            assert!(note.unwrap().starts_with("--backend auto: using the CPU: the GPU probe"), "{exe}");
        }
    }

    #[test]
    fn a_probe_answer_reads_back_as_written() {
        for a in [ProbeAnswer { hardware: Some("NVIDIA H100".into()), error: None }, ProbeAnswer { hardware: None, error: None }] {
            let text = serde_json::to_string(&a).unwrap();
            assert_eq!(serde_json::from_str::<ProbeAnswer>(&text).unwrap(), a);
        }
    }
}
