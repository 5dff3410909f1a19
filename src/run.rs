//! The library side of `dispdec decimate`: load, decimate, re-check, write (atomically), report.

use crate::decimate::{Options, State, Stats};
use crate::topology::topology_summary;
use crate::validate::Recheck;
use crate::eval::{CpuEvaluator, Evaluator, NormalMode};
use crate::mapfile::{MapFile, Record, STATUS_MAPPED, STATUS_PINCHED, STATUS_UNREFERENCED};
use crate::mesh::{self, write_atomic};
use crate::Error;
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
    pub threads: usize,
    pub dmax: f64,
    pub max_abs_d: f64,
    /// Dense vertices failing condition (4) on the initial base, the scan itself (constant
    /// mode only: a vertex there sees only its own faces' normals).
    pub unmapped_at_start: usize,
    pub backend: String,
    pub adapter: String,
    pub collapses: Stats,
    pub recheck: RecheckSummary,
    /// The global check (every dense vertex against the whole base mesh).
    pub global: crate::validate::Verdict,
    pub time: Timings,
}

/// Runs the decimation job; on success every requested output exists, on failure none does.
pub fn decimate(job: &DecimateJob) -> Result<Report, Error> {
    if job.options.batch == 0 {
        return Err(Error::Usage("--batch must be at least 1".into()));
    }
    if let Some(d) = job.options.dmax {
        if !(d > 0.0 && d.is_finite()) {
            return Err(Error::Usage(format!("--dmax must be a positive number, got {d}")));
        }
    }
    if job.options.max_valence < 3 {
        return Err(Error::Usage("--max-valence must be at least 3".into()));
    }
    let pool = rayon::ThreadPoolBuilder::new()
        .num_threads(job.threads.unwrap_or(0))
        .build()
        .map_err(|e| Error::Usage(format!("cannot start {} threads: {e}", job.threads.unwrap_or(0))))?;
    pool.install(|| decimate_in_pool(job))
}

fn decimate_in_pool(job: &DecimateJob) -> Result<Report, Error> {
    let t_start = Instant::now();
    let dense = mesh::load_dense(&job.input)?;
    let t_loaded = Instant::now();
    let (genus, loops_in) = topology_summary(dense.positions.len(), &dense.faces);
    let mut state = State::new(&dense, &job.options);
    let t_init = Instant::now();

    let faces_in = dense.faces.len();
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
    let evaluator = CpuEvaluator;
    state.run(&evaluator, &job.options, |faces| {
        if let Some(pb) = &bar {
            pb.set_position((faces_in - faces) as u64);
            pb.set_message(format!("{faces} faces"));
        }
    });
    if let Some(pb) = &bar {
        pb.finish_and_clear();
    }
    let t_dec = Instant::now();
    let recheck: Recheck = state.recheck();
    let t_check = Instant::now();

    let base = state.compact();
    let global = crate::validate::validate(
        &state.dense,
        &crate::validate::Base { positions: base.positions.clone(), directions: base.directions.clone(), faces: base.faces.clone() },
        job.options.normals,
        state.dmax,
    );
    let (_, loops_out) = topology_summary(base.positions.len(), &base.faces);
    let header = format!(
        "dispdec base mesh: {} faces from {} ({} normals{})\nvn are the directions N used by the displacement map",
        base.faces.len(),
        job.input.display(),
        if job.options.normals == NormalMode::Constant { "constant" } else { "interpolated" },
        if job.options.strict { ", strict" } else { "" }
    );
    let obj = mesh::obj_with_normals(&base.positions, &base.directions, &base.faces, &header);
    let map_bytes = job.map.as_ref().map(|_| {
        let mut records = vec![
            Record { face: u32::MAX, status: STATUS_UNREFERENCED, bary: [0.0; 3], d: 0.0 };
            dense.input_vertex_count
        ];
        for (v, m) in state.assoc.iter().enumerate() {
            records[dense.input_index[v] as usize] = Record {
                face: base.face_map[m.face as usize],
                status: if state.dense.pinched[v] { STATUS_PINCHED } else { STATUS_MAPPED },
                bary: m.bary.map(|b| b as f32),
                d: m.d as f32,
            };
        }
        MapFile {
            base_faces: base.faces.len() as u32,
            dmax: state.dmax as f32,
            constant_normals: job.options.normals == NormalMode::Constant,
            records,
        }
        .to_bytes()
    });
    let faces_out = base.faces.len();
    let mut report = Report {
        input: job.input.display().to_string(),
        output: job.output.display().to_string(),
        faces_in,
        vertices_in: dense.positions.len(),
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
        threads: rayon::current_num_threads(),
        dmax: state.dmax,
        max_abs_d: recheck.max_abs_d,
        unmapped_at_start: state.unmapped_at_start,
        backend: "cpu".into(),
        adapter: evaluator.name(),
        collapses: state.stats.clone(),
        recheck: RecheckSummary {
            valid: recheck.ok(),
            unmapped: recheck.unmapped.len(),
            flipped: recheck.flipped.len(),
            torn: recheck.torn.len(),
            pinched: recheck.pinched,
            ambiguous: recheck.ambiguous,
            first_unmapped: recheck.unmapped.iter().take(10).map(|&v| dense.input_index[v as usize]).collect(),
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
            write_s: 0.0,
            total_s: 0.0,
        },
    };
    // Write everything only now, each atomically; a failure removes what this run wrote.
    let t_w = Instant::now();
    let mut written: Vec<PathBuf> = Vec::new();
    let result = (|| -> Result<(), Error> {
        write_atomic(&job.output, obj.as_bytes())?;
        written.push(job.output.clone());
        if let (Some(p), Some(b)) = (&job.map, &map_bytes) {
            write_atomic(p, b)?;
            written.push(p.clone());
        }
        report.time.write_s = t_w.elapsed().as_secs_f64();
        report.time.total_s = t_start.elapsed().as_secs_f64();
        if let Some(p) = &job.report {
            let json = serde_json::to_string_pretty(&report).expect("report serialises");
            write_atomic(p, json.as_bytes())?;
        }
        Ok(())
    })();
    if let Err(e) = result {
        for p in written {
            let _ = std::fs::remove_file(p);
        }
        return Err(e);
    }
    Ok(report)
}
