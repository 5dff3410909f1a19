//! `dispdec bench`: the CPU and GPU paths side by side on the same inputs — the bunny, the horse,
//! a 200k+ face scan and a ~1M-face sample — each configuration run several times, each run in
//! a process of its own (so that its peak memory is its own), medians reported, with a
//! quadric-error decimator (meshoptimizer) timed to the same face count as the reference.

use crate::decimate::{Options, RingDirections};
use crate::app::run::{decimate, Backend, DecimateJob, Report};
use crate::Error;
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// One configuration of the evaluator.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Config {
    /// The CPU evaluator on one thread.
    Cpu1,
    /// The CPU evaluator on every core.
    Cpu,
    /// The GPU evaluator (WGSL kernels) on the first adapter.
    Gpu,
}

impl Config {
    pub fn name(self) -> &'static str {
        match self {
            Config::Cpu1 => "cpu, 1 thread",
            Config::Cpu => "cpu, all threads",
            Config::Gpu => "gpu",
        }
    }

    /// Its name on the command line (`--configs`, `bench-run --config`).
    pub fn arg(self) -> &'static str {
        match self {
            Config::Cpu1 => "cpu1",
            Config::Cpu => "cpu",
            Config::Gpu => "gpu",
        }
    }
}

/// What to run.
#[derive(Clone, Debug)]
pub struct BenchJob {
    /// Folder of the scans (bunny.ply.gz, horse.ply.gz, igea.ply.gz).
    pub data: PathBuf,
    /// Meshes by name (bunny, horse, igea, turbineblade, sample1m) or path.
    pub meshes: Vec<String>,
    pub configs: Vec<Config>,
    /// Runs per (mesh, configuration); the median is reported.
    pub runs: usize,
    /// Where the generated ~1M-face sample and the outputs go.
    pub work: PathBuf,
    /// The `dispdec` executable each run is measured in: `dispdec bench-run` ([`run_one`]) in a
    /// process of its own.
    pub exe: PathBuf,
    /// Where the caller will write the JSON report: refused before any run if it is one of the
    /// scans.
    pub json: Option<PathBuf>,
    /// The round width every run decimates with (`--batch`; default 16).
    pub batch: usize,
    /// The direction rule every run decimates with (`--ring-directions`).
    pub ring: RingDirections,
}

/// One decimation as `dispdec bench-run` measures it, in its own process.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct RunResult {
    pub faces_in: usize,
    pub faces_out: usize,
    pub threads: usize,
    pub adapter: String,
    /// Valid under the local re-check and the global check.
    pub valid: bool,
    /// This run's seconds per phase and stage.
    pub time: Phases,
    /// GPU runs: the share of kernel answers settled in f64, and the seconds in the kernels.
    pub band_fraction: Option<f64>,
    pub kernel_s: Option<f64>,
    /// The process's peak resident set (MB, 10^6 bytes): everything the run held, the scan
    /// included, and nothing of any other run.
    pub peak_rss_mb: Option<f64>,
}

/// What `dispdec bench-run` writes: the run, or the error it stopped with, as the bench's own
/// process would report it (a bad scan is an input error naming the file; no GPU skips the
/// configuration).
pub type RunOutcome = Result<RunResult, Error>;

/// One measured decimation (the body of `dispdec bench-run`): `input` → `output` in `config`,
/// default options but the round width.
pub fn run_one(input: &Path, output: &Path, config: Config, batch: usize, ring: RingDirections) -> RunOutcome {
    let dj = DecimateJob {
        input: input.to_path_buf(),
        output: output.to_path_buf(),
        map: None,
        report: None,
        options: Options { batch, ring, ..Options::default() },
        threads: Some(if config == Config::Cpu1 { 1 } else { 0 }),
        progress: false,
        backend: if config == Config::Gpu { Backend::Gpu } else { Backend::Cpu },
        probe: Default::default(),
        preparation: Default::default(),
        repaired: None,
    };
    decimate(&dj).map(|r| RunResult::of(&r))
}

impl RunResult {
    fn of(r: &Report) -> RunResult {
        RunResult {
            faces_in: r.faces_in,
            faces_out: r.faces_out,
            threads: r.threads,
            adapter: r.adapter.clone(),
            valid: r.recheck.valid && r.global.valid,
            time: Phases {
                load_s: r.time.load_s,
                init_s: r.time.init_s,
                pick_s: r.time.pick_s,
                evaluate_s: r.time.evaluate_s,
                commit_s: r.time.commit_s,
                slowest_s: r.collapses.time_slowest_candidates_s,
                recheck_s: r.time.recheck_s,
                global_s: r.time.global_s,
                total_s: r.time.total_s,
                stages_cpu_s: r.collapses.stages.stages_cpu_s.clone(),
                rejected_cpu_s: r.collapses.stages.rejected_cpu_s,
            },
            band_fraction: r.gpu_band.as_ref().map(|b| b.band_fraction()),
            kernel_s: r.gpu_band.as_ref().map(|b| b.kernel_s),
            peak_rss_mb: r.peak_rss_mb,
        }
    }
}

/// Runs `dispdec bench-run` for one decimation in a child process and reads its outcome.
fn measure(job: &BenchJob, input: &Path, output: &Path, config: Config) -> Result<RunOutcome, Error> {
    let result = output.with_extension("run.json");
    let _ = std::fs::remove_file(&result);
    let out = std::process::Command::new(&job.exe)
        .arg("bench-run")
        .arg(input)
        .arg(output)
        .args(["--config", config.arg(), "--batch", &job.batch.to_string()])
        .args(["--ring-directions", job.ring.arg(), "--result"])
        .arg(&result)
        .stdin(std::process::Stdio::null())
        .stdout(std::process::Stdio::null())
        .output()
        .map_err(|e| Error::Output { path: job.exe.display().to_string(), msg: format!("cannot run a bench process: {e}") })?;
    let failed = |why: String| Error::Output { path: result.display().to_string(), msg: why };
    let text = std::fs::read(&result).map_err(|_| {
        let err = String::from_utf8_lossy(&out.stderr);
        let tail: Vec<&str> = err.lines().rev().take(5).collect::<Vec<_>>().into_iter().rev().collect();
        failed(format!("the bench process ({}) ended with {} and wrote no result: {}", job.exe.display(), out.status, tail.join(" / ")))
    })?;
    serde_json::from_slice(&text).map_err(|e| failed(format!("unreadable bench result: {e}")))
}

/// The median of a non-empty list.
pub fn median(v: &[f64]) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let n = s.len();
    if n == 0 {
        return f64::NAN;
    }
    if n % 2 == 1 {
        s[n / 2]
    } else {
        0.5 * (s[n / 2 - 1] + s[n / 2])
    }
}

/// Seconds per phase (of one run, or the medians of a row's runs).
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct Phases {
    pub load_s: f64,
    pub init_s: f64,
    pub pick_s: f64,
    pub evaluate_s: f64,
    pub commit_s: f64,
    /// Σ over rounds of each round's slowest candidate (report's
    /// `collapses.time_slowest_candidates_s`; 0 on the GPU path).
    pub slowest_s: f64,
    pub recheck_s: f64,
    pub global_s: f64,
    pub total_s: f64,
    /// The candidate test's CPU seconds per stage (summed over threads; report's
    /// `collapses.stages`), and over candidates that failed every placement.
    pub stages_cpu_s: Vec<(String, f64)>,
    pub rejected_cpu_s: f64,
}

impl Phases {
    /// The median of every field over `runs` (non-empty, with the same stages).
    fn median(runs: &[&Phases]) -> Phases {
        let m = |f: fn(&Phases) -> f64| median(&runs.iter().map(|p| f(p)).collect::<Vec<_>>());
        Phases {
            load_s: m(|p| p.load_s),
            init_s: m(|p| p.init_s),
            pick_s: m(|p| p.pick_s),
            evaluate_s: m(|p| p.evaluate_s),
            commit_s: m(|p| p.commit_s),
            slowest_s: m(|p| p.slowest_s),
            recheck_s: m(|p| p.recheck_s),
            global_s: m(|p| p.global_s),
            total_s: m(|p| p.total_s),
            stages_cpu_s: runs[0]
                .stages_cpu_s
                .iter()
                .enumerate()
                .map(|(i, (name, _))| (name.clone(), median(&runs.iter().map(|p| p.stages_cpu_s[i].1).collect::<Vec<_>>())))
                .collect(),
            rejected_cpu_s: m(|p| p.rejected_cpu_s),
        }
    }
}

/// One (mesh, configuration) row.
#[derive(Clone, Debug, Serialize)]
pub struct Row {
    pub mesh: String,
    pub faces_in: usize,
    pub config: Config,
    pub threads: usize,
    pub adapter: String,
    /// Faces out of every run (identical unless something is wrong).
    pub faces_out: Vec<usize>,
    /// Every run valid under the local re-check and the global check.
    pub valid: bool,
    pub runs_total_s: Vec<f64>,
    pub median: Phases,
    /// Largest peak resident memory over the runs (MB, 10^6 bytes), each run measured in a
    /// process of its own (Linux VmHWM: the scan, the decimation, the checks and the process's
    /// own code); `null` where the OS does not say.
    pub peak_rss_mb: Option<f64>,
    /// GPU rows: fraction of kernel answers that fell in the tolerance band (settled in f64).
    pub band_fraction: Option<f64>,
    /// GPU rows: median seconds inside the kernels (upload, dispatch, readback); the rest of
    /// `evaluate_s` is CPU work (neighbourhoods, the band in f64, flip and tear checks).
    pub gpu_kernel_s: Option<f64>,
    /// meshoptimizer `simplify` to the same face count: median seconds, and this row's median
    /// total over it.
    pub meshopt_s: f64,
    pub ratio_to_meshopt: f64,
}

/// The whole benchmark.
#[derive(Clone, Debug, Serialize)]
pub struct BenchReport {
    pub machine: String,
    pub cores: usize,
    pub runs: usize,
    /// The round width of every run (`--batch`).
    pub batch: usize,
    /// The direction rule of every run (`--ring-directions`).
    pub ring_directions: RingDirections,
    pub rows: Vec<Row>,
    /// Configurations that could not run here, and why.
    pub skipped: Vec<String>,
}

fn machine_name() -> String {
    let cpu = std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| s.lines().find(|l| l.starts_with("model name")).and_then(|l| l.split(':').nth(1)).map(|s| s.trim().to_string()))
        .unwrap_or_else(|| std::env::consts::ARCH.to_string());
    format!("{cpu}, {} cores, {}", std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1), std::env::consts::OS)
}


/// The scans' own file names, by the names `--meshes` knows.
fn known_scan(name: &str) -> Option<&'static str> {
    Some(match name {
        "bunny" => "bunny.ply.gz",
        "horse" => "horse.ply.gz",
        "igea" => "igea.ply.gz",
        "turbineblade" => "turbineblade.ply.gz",
        _ => return None,
    })
}

/// The file a mesh name stands for, as given: a known scan in the scans' folder or a file of
/// the user's; `None` for the 1M sample, which is generated.
fn named_file(job: &BenchJob, name: &str) -> Option<PathBuf> {
    match (known_scan(name), name) {
        (Some(file), _) => Some(job.data.join(file)),
        (None, "sample1m") => None,
        (None, other) => Some(PathBuf::from(other)),
    }
}

/// The input file of a mesh name (the 1M sample is generated into `work` once).
fn mesh_path(job: &BenchJob, name: &str) -> Result<PathBuf, Error> {
    let Some(p) = named_file(job, name) else {
        let p = job.work.join("sample-1m.obj");
        if !p.exists() {
            let m = crate::mesh::sample::generate(crate::mesh::sample::SampleSpec { faces: 1_000_000, seed: 1 });
            let text = crate::mesh::sample::to_obj(&m, "dispdec sample surface (dispdec sample --faces 1000000 --seed 1)");
            crate::mesh::write_atomic(&p, text.as_bytes())?;
        }
        return Ok(p);
    };
    match known_scan(name) {
        // Any other name is a mesh file of the user's.
        None if !p.is_file() => Err(Error::Usage(format!(
            "bench: {name:?} is neither a known mesh (bunny, horse, igea, turbineblade, sample1m) nor a file"
        ))),
        Some(_) if !p.exists() => Err(Error::Input { path: p.display().to_string(), msg: "not found (give the scans' folder with --data)".into() }),
        _ => Ok(p),
    }
}

/// A scan in meshoptimizer's layout (f32 positions, flat indices), loaded once per mesh.
struct QuadricInput {
    verts: Vec<[f32; 3]>,
    indices: Vec<u32>,
}

impl QuadricInput {
    fn load(path: &Path) -> Result<QuadricInput, Error> {
        let scan = crate::mesh::load_dense(path)?;
        Ok(QuadricInput {
            verts: scan.positions.iter().map(|p| [p.x as f32, p.y as f32, p.z as f32]).collect(),
            indices: scan.faces.iter().flatten().copied().collect(),
        })
    }

    /// meshoptimizer's `simplify` to `faces` faces: the median seconds of `runs` runs (3 at least).
    fn time(&self, path: &Path, faces: usize, runs: usize) -> Result<f64, Error> {
        let adapter = meshopt::VertexDataAdapter::new(bytemuck::cast_slice(&self.verts), 12, 0)
            .map_err(|e| Error::Input { path: path.display().to_string(), msg: format!("meshopt: {e}") })?;
        let mut times = Vec::new();
        for _ in 0..runs.max(3) {
            let t = Instant::now();
            let out = meshopt::simplify(&self.indices, &adapter, faces * 3, 1.0, meshopt::SimplifyOptions::empty(), None);
            times.push(t.elapsed().as_secs_f64());
            std::hint::black_box(out);
        }
        Ok(median(&times))
    }
}

/// Runs the benchmark; `progress` gets one line per finished run.
pub fn bench(job: &BenchJob, mut progress: impl FnMut(&str)) -> Result<BenchReport, Error> {
    if job.runs == 0 {
        return Err(Error::Usage("--runs must be at least 1".into()));
    }
    crate::app::run::check_batch(job.batch)?;
    if let Some(json) = &job.json {
        let scans: Vec<PathBuf> = job.meshes.iter().filter_map(|m| named_file(job, m)).collect();
        crate::app::outputs::check_outputs(&scans.iter().map(PathBuf::as_path).collect::<Vec<_>>(), &[("the report", json)])?;
    }
    std::fs::create_dir_all(&job.work).map_err(|e| Error::Output { path: job.work.display().to_string(), msg: e.to_string() })?;
    let cores = std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1);
    let mut rows = Vec::new();
    let mut skipped = Vec::new();
    let mut gpu_ok = true;
    for name in &job.meshes {
        let path = mesh_path(job, name)?;
        let quadric = QuadricInput::load(&path)?;
        let mut reference_faces = None;
        for &config in &job.configs {
            if config == Config::Gpu && !gpu_ok {
                continue;
            }
            let mut reports: Vec<RunResult> = Vec::new();
            for run in 0..job.runs.max(1) {
                // In the work folder whatever the mesh (a user's path names only its file).
                let stem = Path::new(name).file_name().map_or_else(|| name.clone(), |f| f.to_string_lossy().into_owned());
                let out = job.work.join(format!("{stem}-{config:?}.obj"));
                match measure(job, &path, &out, config)? {
                    Ok(r) => {
                        progress(&format!(
                            "{name} ({} faces), {}, run {}/{}: {} faces in {:.2} s, peak {}",
                            r.faces_in,
                            config.name(),
                            run + 1,
                            job.runs.max(1),
                            r.faces_out,
                            r.time.total_s,
                            r.peak_rss_mb.map_or("-".into(), |p| format!("{p:.1} MB"))
                        ));
                        reports.push(r);
                    }
                    Err(Error::Gpu(e)) => {
                        skipped.push(format!("gpu: {e}"));
                        gpu_ok = false;
                        break;
                    }
                    Err(e) => return Err(e),
                }
            }
            if reports.is_empty() {
                continue;
            }
            let faces_out: Vec<usize> = reports.iter().map(|r| r.faces_out).collect();
            let target = *reference_faces.get_or_insert(faces_out[0]);
            let meshopt_s = quadric.time(&path, target, job.runs)?;
            let phases = Phases::median(&reports.iter().map(|r| &r.time).collect::<Vec<_>>());
            let kernel_s = reports[0].kernel_s.map(|_| median(&reports.iter().map(|r| r.kernel_s.unwrap_or(0.0)).collect::<Vec<_>>()));
            rows.push(Row {
                mesh: name.clone(),
                faces_in: reports[0].faces_in,
                config,
                threads: reports[0].threads,
                adapter: reports[0].adapter.clone(),
                valid: reports.iter().all(|r| r.valid),
                runs_total_s: reports.iter().map(|r| r.time.total_s).collect(),
                ratio_to_meshopt: phases.total_s / meshopt_s,
                median: phases,
                faces_out,
                peak_rss_mb: reports.iter().filter_map(|r| r.peak_rss_mb).reduce(f64::max),
                band_fraction: reports[0].band_fraction,
                gpu_kernel_s: kernel_s,
                meshopt_s,
            });
        }
    }
    Ok(BenchReport { machine: machine_name(), cores, runs: job.runs.max(1), batch: job.batch, ring_directions: job.ring, rows, skipped })
}

/// The table `dispdec bench` prints (Markdown, so that the README can show it as is).
pub fn table(r: &BenchReport) -> String {
    let mut s = format!("machine: {}; median of {} run(s) each", r.machine, r.runs);
    if r.batch != Options::default().batch {
        s += &format!("; --batch {}", r.batch);
    }
    if r.ring_directions != RingDirections::default() {
        s += &format!("; --ring-directions {}", r.ring_directions.arg());
    }
    s += "\n\n";
    s += "| mesh | faces in | path | faces out | total s | evaluate s (in kernels) | pick+commit s | checks s | peak MB (B/face) | band | meshopt ms | × meshopt |\n";
    s += "|---|---:|---|---|---:|---:|---:|---:|---:|---:|---:|---:|\n";
    for row in &r.rows {
        let m = &row.median;
        let path = match row.config {
            Config::Gpu => format!("gpu: {}", row.adapter.trim_start_matches("gpu: ")),
            c => c.name().to_string(),
        };
        let faces: Vec<String> = row.faces_out.iter().map(|f| f.to_string()).collect();
        let mut faces = faces.join("/");
        if !row.valid {
            faces += " INVALID";
        }
        s += &format!(
            "| {} | {} | {} | {} | {:.2} | {:.2}{} | {:.2} | {:.2} | {} | {} | {:.1} | {:.0} |\n",
            row.mesh,
            row.faces_in,
            path,
            faces,
            m.total_s,
            m.evaluate_s,
            row.gpu_kernel_s.map_or(String::new(), |k| format!(" ({k:.2})")),
            m.pick_s + m.commit_s,
            m.recheck_s + m.global_s,
            row.peak_rss_mb.map_or("-".into(), |p| format!("{p:.0} ({:.0})", p * 1e6 / row.faces_in.max(1) as f64)),
            row.band_fraction.map_or("-".into(), |b| format!("{:.1} %", 100.0 * b)),
            1000.0 * row.meshopt_s,
            row.ratio_to_meshopt
        );
    }
    // Where the time goes: the candidate test's stages (CPU seconds summed over threads), the
    // serial pick and commit, and the evaluation's wall against its rounds' slowest candidates
    // (wall seconds), medians.
    if let Some(first) = r.rows.first() {
        let names: Vec<&str> = first.median.stages_cpu_s.iter().map(|(n, _)| n.as_str()).collect();
        s += &format!("\nstages (median s; the test's stages are CPU seconds summed over threads)\n\n| mesh | path | {} | pick | commit | evaluate (rounds' slowest) | 1 → {} threads |\n", names.join(" | "), r.cores);
        s += &format!("|---|---|{}---:|---:|---:|---:|\n", "---:|".repeat(names.len()));
        for row in &r.rows {
            let m = &row.median;
            let stages: Vec<String> = m.stages_cpu_s.iter().map(|(_, v)| format!("{v:.2}")).collect();
            // The speed-up of all threads over one, where both rows exist for this mesh.
            let speedup = match row.config {
                Config::Cpu => r
                    .rows
                    .iter()
                    .find(|o| o.mesh == row.mesh && o.config == Config::Cpu1)
                    .map_or("-".into(), |o| format!("{:.2}×", o.median.total_s / m.total_s)),
                _ => "-".into(),
            };
            s += &format!("| {} | {} | {} | {:.2} | {:.2} | {:.2} ({:.2}) | {} |\n", row.mesh, row.config.name(), stages.join(" | "), m.pick_s, m.commit_s, m.evaluate_s, m.slowest_s, speedup);
        }
    }
    for sk in &r.skipped {
        s += &format!("\nnot run: {sk}\n");
    }
    s
}
