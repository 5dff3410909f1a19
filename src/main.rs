//! The `dispdec` command line: clap parses into the library's option structs; the library
//! does the work.

use anyhow::Result;
use clap::{Parser, Subcommand, ValueEnum};
use dispdec::decimate::{NearRule, Options, RingDirections, DEFAULT_MAX_VALENCE};
use dispdec::eval::NormalMode;
use dispdec::app::run::{decimate, DecimateJob};
use std::io::IsTerminal;
use std::path::PathBuf;

#[derive(Parser)]
#[command(name = "dispdec", version, about = "Decimate dense scans into base meshes that carry them as displacement maps")]
struct Cli {
    #[command(subcommand)]
    cmd: Cmd,
    /// Also print what the GPU probe and the Vulkan loader say, and which backend `auto` chose.
    #[arg(long, global = true)]
    verbose: bool,
    /// Print nothing but errors (no progress bar, no summary, no warnings).
    #[arg(long, short, global = true)]
    quiet: bool,
}

/// How the scan is prepared before it is checked: welding (on by default) and `--repair`.
#[derive(clap::Args, Clone, Copy, Debug)]
struct PrepArgs {
    /// Keep exactly coincident vertices apart (by default they are welded into one).
    #[arg(long)]
    no_weld: bool,
    /// Clean up what raw scans carry, counted in the report: drop degenerate and duplicate
    /// faces, remove the fewest faces that make every edge manifold, wind each component
    /// consistently, split non-manifold vertices into their fans.
    #[arg(long)]
    repair: bool,
    /// With --repair: drop components of fewer faces than this (default: keep them all).
    #[arg(long, requires = "repair")]
    min_component: Option<usize>,
}

impl PrepArgs {
    fn preparation(&self) -> dispdec::mesh::repair::Preparation {
        dispdec::mesh::repair::Preparation { weld: !self.no_weld, repair: self.repair, min_component: self.min_component.unwrap_or(0) }
    }
}

fn flags(prep: &PrepArgs, normals: Option<Normals>, dmax: Option<f64>, strict: Option<bool>) -> dispdec::settings::Flags {
    dispdec::settings::Flags {
        normals: normals.map(mode_of),
        dmax,
        strict,
        no_weld: prep.no_weld,
        repair: prep.repair,
        min_component: prep.min_component,
    }
}

fn mode_of(n: Normals) -> NormalMode {
    match n {
        Normals::Interpolated => NormalMode::Interpolated,
        Normals::Constant => NormalMode::Constant,
    }
}

#[derive(Clone, Copy, ValueEnum)]
enum Normals {
    Interpolated,
    Constant,
}

#[derive(Clone, Copy, ValueEnum)]
enum MapKind {
    /// d along the unnormalised interpolated direction N(X) (dispdec's own).
    Scalar,
    /// d·|N(X)|: the distance along the normalised interpolated normal (engines, viewers).
    Normalized,
    /// The object-space vector d·N(X) in RGB (Blender's Displace, RGB to XYZ).
    Vector,
}

#[derive(Clone, Copy, ValueEnum)]
enum NearRuleArg {
    Box,
    Triangles,
}

#[derive(Clone, Copy, ValueEnum)]
enum RingArg {
    /// SPEC §2: u and every vertex of the ring of u and w get new directions (region: 2-ring).
    Recompute,
    /// Only u does; the ring keeps its directions (region: the faces around u and w).
    Keep,
}

fn ring_of(r: RingArg) -> RingDirections {
    match r {
        RingArg::Recompute => RingDirections::Recompute,
        RingArg::Keep => RingDirections::Keep,
    }
}

#[derive(Clone, Copy, ValueEnum)]
enum Backend {
    Cpu,
    Gpu,
    Auto,
}

#[derive(Clone, Copy, ValueEnum)]
enum BenchConfig {
    /// The CPU evaluator on one thread.
    Cpu1,
    /// The CPU evaluator on every core.
    Cpu,
    /// The GPU evaluator (WGSL kernels).
    Gpu,
}

fn bench_config(c: BenchConfig) -> dispdec::app::bench::Config {
    match c {
        BenchConfig::Cpu1 => dispdec::app::bench::Config::Cpu1,
        BenchConfig::Cpu => dispdec::app::bench::Config::Cpu,
        BenchConfig::Gpu => dispdec::app::bench::Config::Gpu,
    }
}

#[derive(Subcommand)]
enum Cmd {
    /// Benchmark the CPU and GPU paths on the same inputs (medians of --runs runs), with
    /// meshoptimizer's quadric simplifier to the same face count as the reference.
    Bench {
        /// JSON report.
        #[arg(long)]
        json: Option<PathBuf>,
        /// Runs per mesh and path (the median is reported).
        #[arg(long, default_value_t = 1)]
        runs: usize,
        /// Folder of the scans (default: $DISPDEC_DATA, else ../shared/data).
        #[arg(long)]
        data: Option<PathBuf>,
        /// Meshes: bunny, horse, igea (268k faces), turbineblade (199k), sample1m (generated), or
        /// paths of your own.
        /// The default (the bunny, one run, both CPU paths) takes a few minutes on two cores;
        /// the heavier sets are opt-in.
        #[arg(long, value_delimiter = ',', default_value = "bunny")]
        meshes: Vec<String>,
        /// Paths to compare (gpu: the GPU evaluator on the first adapter; on Mesa's lavapipe it
        /// is several times slower than the CPU path).
        #[arg(long, value_enum, value_delimiter = ',', default_value = "cpu1,cpu")]
        configs: Vec<BenchConfig>,
        /// Folder for the generated sample and the outputs (default: a temporary folder).
        #[arg(long)]
        work: Option<PathBuf>,
        /// The round width of every run, as `decimate --batch`.
        #[arg(long, default_value_t = Options::default().batch)]
        batch: usize,
        /// The direction rule of every run, as `decimate --ring-directions`.
        #[arg(long, value_enum, default_value = "recompute")]
        ring_directions: RingArg,
    },
    /// One run of `dispdec bench`, in a process of its own (so that its peak memory is its own):
    /// decimates INPUT into OUTPUT with default options (but the bench's `--batch`) and writes
    /// what was measured as JSON.
    #[command(hide = true)]
    BenchRun {
        input: PathBuf,
        output: PathBuf,
        #[arg(long, value_enum)]
        config: BenchConfig,
        /// The round width (`decimate --batch`).
        #[arg(long, default_value_t = Options::default().batch)]
        batch: usize,
        /// The direction rule (`decimate --ring-directions`).
        #[arg(long, value_enum, default_value = "recompute")]
        ring_directions: RingArg,
        /// Where the measurement goes (JSON).
        #[arg(long)]
        result: PathBuf,
    },
    /// `--backend auto`'s probe for a hardware GPU adapter, run by dispdec in a process of its
    /// own (so that the drivers it loads never stay resident in a run that chooses the CPU);
    /// prints the answer as JSON.
    #[command(hide = true)]
    ProbeGpu,
    /// Decimate INPUT (OBJ, PLY, STL or glTF, optionally .gz) into a base mesh.
    Decimate {
        input: PathBuf,
        /// The base mesh (OBJ with one vn per v and f v//vn).
        #[arg(short, long)]
        output: PathBuf,
        /// Per dense vertex: base face, barycentrics and d (binary, see README).
        #[arg(long)]
        map: Option<PathBuf>,
        /// JSON report.
        #[arg(long)]
        report: Option<PathBuf>,
        #[arg(long, value_enum, default_value = "interpolated")]
        normals: Normals,
        /// Stop at this many faces (default: as far as the guarantee allows).
        #[arg(long)]
        target_faces: Option<usize>,
        /// An edge collapses only if valence(u) + valence(w) - 1 is below this.
        #[arg(long, default_value_t = DEFAULT_MAX_VALENCE)]
        max_valence: u32,
        /// Largest |d| (default: 0.1 x the bounding-box diagonal of INPUT).
        #[arg(long)]
        dmax: Option<f64>,
        /// The paper's uniqueness rule: exactly one solution satisfying (4) per dense vertex.
        #[arg(long)]
        strict: bool,
        /// Where batches are evaluated: cpu, gpu (WGSL kernels; fails without an adapter), or
        /// auto (a hardware GPU if there is one, else the CPU, saying why).
        #[arg(long, value_enum, default_value = "auto")]
        backend: Backend,
        /// Worker threads (default: all cores).
        #[arg(long)]
        threads: Option<usize>,
        /// Candidates evaluated per round (1 = the paper's serial algorithm).
        #[arg(long, default_value_t = Options::default().batch)]
        batch: usize,
        /// Which dense vertices' edges a candidate walks again besides its own: those within
        /// |d| + half their longest edge of the collapsed region's triangles (triangles), or of
        /// the box around them (box: the earlier rule, same verdicts, more edges walked).
        #[arg(long, value_enum, default_value = "triangles")]
        near_rule: NearRuleArg,
        /// Every check (the candidate test, the re-check, the global check) walks each image
        /// loop that passes as sampled again at 8 pieces an edge, and at 64 where that is
        /// negative, as `validate --fine-loops` does: finer than SPEC's sampled image, and
        /// slower (README, The exact guarantee).
        #[arg(long)]
        fine_loops: bool,
        /// Which base vertices a collapse gives a new direction: u and the ring of u and w
        /// (recompute, SPEC §2: the test solves the edge's 2-ring again), or u alone (keep: the
        /// ring keeps its directions, the test solves the faces around u and w; faster, and
        /// the runs go further; README, Decisions).
        #[arg(long, value_enum, default_value = "recompute")]
        ring_directions: RingArg,
        #[command(flatten)]
        prep: PrepArgs,
        /// Write the scan as decimated (welded, repaired) to this OBJ (.obj or .obj.gz), so that
        /// any validator can judge the base against exactly that mesh.
        #[arg(long)]
        repaired: Option<PathBuf>,
    },
    /// Judge BASE against HIGH from scratch: can BASE carry HIGH as a displacement map?
    /// Exit 0 when valid, 1 when not, 2 on bad input.
    Validate {
        high: PathBuf,
        base: PathBuf,
        /// JSON report.
        #[arg(long)]
        json: Option<PathBuf>,
        /// Fold image (PNG): green = covered once, white = fold, red = hole.
        #[arg(long)]
        fold_image: Option<PathBuf>,
        /// The scan's failing triangles as an OBJ (F.obj or F.obj.gz), one object per kind
        /// (flipped, torn, unmapped), in the scan's coordinates: open it over HIGH to see where
        /// BASE fails.
        #[arg(long, value_name = "F.obj")]
        failures: Option<PathBuf>,
        /// Atlas size in texels.
        #[arg(long, default_value_t = 1024)]
        resolution: u32,
        /// Largest |d| (default: the dmax BASE was made with, else 0.1 x the bounding-box
        /// diagonal of HIGH).
        #[arg(long)]
        dmax: Option<f64>,
        /// The paper's uniqueness rule: an ambiguous vertex makes BASE invalid (default: on when
        /// BASE was made with --strict).
        #[arg(long, conflicts_with = "no_strict")]
        strict: bool,
        /// Judge without the uniqueness rule even if BASE was made with --strict.
        #[arg(long)]
        no_strict: bool,
        /// Normal mode (default: the one BASE was made with, else interpolated).
        #[arg(long, value_enum)]
        normals: Option<Normals>,
        #[command(flatten)]
        prep: PrepArgs,
        /// Where the projection runs: cpu, gpu, or auto (as for decimate).
        #[arg(long, value_enum, default_value = "auto")]
        backend: Backend,
        /// Worker threads (default: all cores).
        #[arg(long)]
        threads: Option<usize>,
        /// Brute force: every dense point against every base triangle, no BVH and no culling
        /// (slow; cross-checks the fast path). Runs on the CPU.
        #[arg(long)]
        exhaustive: bool,
        /// Also walk every image loop that passes again at 8 pieces an edge, and at 64 where
        /// that is negative: a loop negative at both is flipped (finer than SPEC's sampled
        /// image, which the decimator guarantees by default; counted as fine_flipped /
        /// fine_torn). Default: on when BASE was made with `decimate --fine-loops`.
        #[arg(long)]
        fine_loops: bool,
    },
    /// Bake the displacement map of HIGH over BASE's atlas: DISP.exr or DISP.pfm (32-bit float)
    /// or DISP.png (16-bit), with DISP.ext.json (kind, quantisation) and DISP.obj (BASE with the
    /// map's UVs) beside it.
    Bake {
        high: PathBuf,
        base: PathBuf,
        /// The decimator's BASE.map: report how closely the baked map reproduces its d.
        #[arg(long)]
        map: Option<PathBuf>,
        #[arg(short, long)]
        output: PathBuf,
        /// Atlas size in texels.
        #[arg(long, default_value_t = 2048)]
        resolution: u32,
        /// Largest |d| searched (default: the dmax BASE was made with, else 0.1 x the
        /// bounding-box diagonal of HIGH).
        #[arg(long)]
        dmax: Option<f64>,
        /// What a texel holds.
        #[arg(long, value_enum, default_value = "scalar")]
        kind: MapKind,
        /// Normal mode (default: the one BASE was made with, else interpolated).
        #[arg(long, value_enum)]
        normals: Option<Normals>,
        #[command(flatten)]
        prep: PrepArgs,
    },
    /// Rebuild the scan: subdivide BASE --levels times and displace by DISP.
    Reconstruct {
        base: PathBuf,
        disp: PathBuf,
        #[arg(long, default_value_t = 5)]
        levels: u32,
        #[arg(short, long)]
        output: PathBuf,
        /// Measure every level against this scan (RMS and Hausdorff, both ways).
        #[arg(long)]
        compare: Option<PathBuf>,
        /// With --compare: a PNG chart of the errors against level.
        #[arg(long)]
        plot: Option<PathBuf>,
        /// Normal mode (default: the one BASE was made with, else interpolated).
        #[arg(long, value_enum)]
        normals: Option<Normals>,
    },
    /// Write a binary glTF (.glb): BASE with normals, UVs and the map DISP as a 16-bit PNG
    /// texture (normalized convention, in the material's extras), and with --levels the mesh
    /// rebuilt at that level as a second node.
    Export {
        base: PathBuf,
        disp: PathBuf,
        #[arg(short, long)]
        output: PathBuf,
        #[arg(long)]
        levels: Option<u32>,
    },
    /// Render meshes side by side (headless wgpu; lavapipe works) into a PNG.
    Render {
        #[arg(required = true)]
        meshes: Vec<PathBuf>,
        #[arg(short, long)]
        output: PathBuf,
        /// Pixels per mesh.
        #[arg(long, default_value_t = 400)]
        size: u32,
        /// Turn about the vertical axis (degrees).
        #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
        yaw: f64,
        /// Then tilt about the horizontal axis (degrees).
        #[arg(long, default_value_t = 0.0, allow_hyphen_values = true)]
        pitch: f64,
        /// Draw this OBJ's triangles in red over the first mesh, in its coordinates: the
        /// output of `validate --failures` over the scan shows where a base fails.
        #[arg(long, value_name = "F.obj")]
        mark: Option<PathBuf>,
    },
    /// Generate a scan-like sample mesh (bumps, a thin fin, an overhang, an open boundary).
    Sample {
        #[arg(short, long)]
        output: PathBuf,
        #[arg(long, default_value_t = 100_000)]
        faces: usize,
        #[arg(long, default_value_t = 1)]
        seed: u64,
    },
}

fn main() {
    dispdec::app::memory::keep_heap_compact();
    let cli = Cli::parse();
    if !cli.verbose && std::env::var_os("NODEVICE_SELECT").is_none() {
        // Mesa's device-select Vulkan layer prints an XDG_RUNTIME_DIR line on every adapter
        // probe of a headless machine; it chooses nothing dispdec needs. Set before any thread
        // or Vulkan instance exists.
        std::env::set_var("NODEVICE_SELECT", "1");
    }
    match run(cli) {
        Ok(code) => std::process::exit(code),
        Err(e) => {
            // Only "the check failed" is 1 (SPEC §6); every other failure is 2.
            let code = e.downcast_ref::<dispdec::Error>().map(|e| e.exit_code()).unwrap_or(2);
            eprintln!("dispdec: error: {e}");
            std::process::exit(code);
        }
    }
}

fn backend_of(backend: Backend) -> dispdec::app::run::Backend {
    match backend {
        Backend::Cpu => dispdec::app::run::Backend::Cpu,
        Backend::Gpu => dispdec::app::run::Backend::Gpu,
        Backend::Auto => dispdec::app::run::Backend::Auto,
    }
}

/// `--backend auto` probes in a child process (this binary's `probe-gpu`), so that a run
/// that chooses the CPU never holds the Vulkan drivers (lavapipe: ~50 MB resident); in this
/// process where the binary cannot name itself.
fn probe(say: &Say) -> dispdec::app::run::Probe {
    match std::env::current_exe() {
        Ok(exe) => dispdec::app::run::Probe::Child { exe, show_stderr: say.verbose && !say.quiet },
        Err(_) => dispdec::app::run::Probe::InProcess,
    }
}

/// What goes to stderr besides errors: the summary and warnings unless `--quiet`, the
/// backend note only with `--verbose`.
struct Say {
    quiet: bool,
    verbose: bool,
}

impl Say {
    fn line(&self, s: &str) {
        if !self.quiet {
            eprintln!("{s}");
        }
    }
    fn warnings(&self, w: &[String]) {
        for s in w {
            self.line(&format!("dispdec: warning: {s}"));
        }
    }
    fn note(&self, note: &Option<String>) {
        if let (true, Some(n)) = (self.verbose && !self.quiet, note) {
            eprintln!("dispdec: {n}");
        }
    }
}

fn run(cli: Cli) -> Result<i32> {
    let say = Say { quiet: cli.quiet, verbose: cli.verbose };
    match cli.cmd {
        Cmd::Decimate {
            input,
            output,
            map,
            report,
            normals,
            target_faces,
            max_valence,
            dmax,
            strict,
            backend,
            threads,
            batch,
            near_rule,
            fine_loops,
            ring_directions,
            prep,
            repaired,
        } => {
            let job = DecimateJob {
                backend: backend_of(backend),
                probe: probe(&say),
                input,
                output,
                map,
                report,
                options: Options {
                    normals: mode_of(normals),
                    target_faces: target_faces.unwrap_or(0),
                    max_valence,
                    dmax,
                    strict,
                    batch,
                    near: match near_rule {
                        NearRuleArg::Box => NearRule::Box,
                        NearRuleArg::Triangles => NearRule::Triangles,
                    },
                    loops: dispdec::guarantee::LoopSampling::fine_if(fine_loops),
                    ring: ring_of(ring_directions),
                },
                threads,
                progress: !say.quiet && std::io::stderr().is_terminal(),
                preparation: prep.preparation(),
                repaired,
            };
            let r = decimate(&job)?;
            say.warnings(&r.warnings);
            say.note(&r.backend_note);
            let c = &r.input_cleanup;
            if c.repaired {
                say.line(&format!(
                    "{}: repaired: {} degenerate and {} duplicate faces dropped, {} faces removed at {} non-manifold edges, {} faces re-wound, {} non-manifold vertices split ({} copies), {} of {} components dropped ({} faces)",
                    r.input,
                    c.degenerate_faces,
                    c.duplicate_faces,
                    c.non_manifold_edge_faces_removed,
                    c.non_manifold_edges,
                    c.flipped_faces,
                    c.non_manifold_vertices,
                    c.vertex_copies,
                    c.components_dropped,
                    c.components + c.components_dropped,
                    c.component_faces_dropped
                ));
            }
            say.line(&format!(
                "{}: {} -> {} faces ({:.2} % decimated{}{}) in {:.1} s; local re-check: {} (unmapped {}, flipped {}, torn {}, pinched {}); global check: {}; max |d| {:.4} of dmax {:.4}",
                r.input,
                r.faces_in,
                r.faces_out,
                r.percent_decimated,
                if c.welded_vertices > 0 { format!(", {} vertices welded", c.welded_vertices) } else { String::new() },
                if c.components > 1 { format!(", {} components", c.components) } else { String::new() },
                r.time.total_s,
                if r.recheck.valid { "carries the scan" } else { "FAILED" },
                r.recheck.unmapped,
                r.recheck.flipped,
                r.recheck.torn,
                r.recheck.pinched,
                if r.global.valid {
                    "valid".to_string()
                } else {
                    format!(
                        "INVALID (unmapped {}, flipped {}, torn {}, jump edges {}{})",
                        r.global.unmapped,
                        r.global.flipped,
                        r.global.torn,
                        r.global.checks.jump_edges,
                        if r.global.strict { format!(", ambiguous {}", r.global.ambiguous) } else { String::new() }
                    )
                },
                r.max_abs_d,
                r.dmax
            ));
            if !(r.recheck.valid && r.global.valid) {
                eprintln!("dispdec: the final check of the guarantee failed; outputs are written, see the report (`dispdec validate SCAN BASE --failures F.obj` writes where it fails)");
                return Ok(1);
            }
            Ok(0)
        }
        Cmd::Validate { high, base, json, fold_image, failures, resolution, dmax, strict, no_strict, normals, prep, backend, threads, exhaustive, fine_loops } => {
            let job = dispdec::app::run::ValidateJob {
                exhaustive,
                fine_loops,
                backend: backend_of(backend),
                probe: probe(&say),
                high,
                base,
                json,
                fold_image,
                failures,
                resolution,
                flags: flags(&prep, normals, dmax, if strict { Some(true) } else if no_strict { Some(false) } else { None }),
                threads,
            };
            let r = dispdec::app::run::validate(&job)?;
            let v = &r.verdict;
            say.warnings(&r.warnings);
            say.note(&r.backend_note);
            say.line(&format!(
                "{} against {}: {} ({} dense vertices: {} mapped, {} unmapped, {} pinched, {} ambiguous, {} far hits; {} dense faces: {} flipped, {} torn; {} jump edges, largest jump {:.3e}; {} straddling faces judged in charts){}{}; max |d| {:.4}, RMS d {:.4}, dmax {:.4}; coverage per base face {:.3}..{:.3}, {} fold and {} hole texels; {:.2} s",
                r.base,
                r.high,
                if v.valid { "VALID" } else { "INVALID" },
                v.dense_vertices,
                v.mapped,
                v.unmapped,
                v.pinched,
                v.ambiguous,
                v.far_hits,
                v.dense_faces,
                v.flipped,
                v.torn,
                v.checks.jump_edges,
                v.checks.max_jump,
                v.checks.straddling,
                match (v.exhaustive, v.fine_loops) {
                    (false, false) => String::new(),
                    (e, f) => format!(
                        " [{}{}]",
                        if e { "exhaustive" } else { "" },
                        if f {
                            format!(
                                "{}fine loops: {} flipped, {} torn ({} with an edge point that has no solution; largest jump {:.3e}) that pass as sampled",
                                if e { "; " } else { "" },
                                v.checks.fine_flipped,
                                v.checks.fine_torn,
                                v.checks.fine_gaps,
                                v.checks.fine_max_jump
                            )
                        } else {
                            String::new()
                        }
                    ),
                },
                if v.exempt_edges > 0 || v.exempt_constant > 0 {
                    format!(
                        "; constant mode: {} vertices and {} edges exempt (the scan itself cannot map them; their triangles are not drawn)",
                        v.exempt_constant, v.exempt_edges
                    )
                } else {
                    String::new()
                },
                v.max_abs_d,
                v.rms_d,
                v.dmax,
                r.coverage.min,
                r.coverage.max,
                r.coverage.folded_texels,
                r.coverage.hole_texels,
                r.time_s
            ));
            for f in r.first_failures.iter().take(10) {
                say.line(&format!("  {} {} at ({:.5}, {:.5}, {:.5})", f.kind, f.index, f.position[0], f.position[1], f.position[2]));
            }
            match &job.failures {
                Some(p) => say.line(&format!("wrote {} (the failing triangles, one object per kind)", p.display())),
                None if !v.valid => say.line("  (every failing triangle, to open over the scan: --failures F.obj)"),
                None => {}
            }
            Ok(if v.valid { 0 } else { 1 })
        }
        Cmd::Bake { high, base, map, output, resolution, dmax, kind, normals, prep } => {
            let kind = match kind {
                MapKind::Scalar => dispdec::maps::bake::Kind::Scalar,
                MapKind::Normalized => dispdec::maps::bake::Kind::Normalized,
                MapKind::Vector => dispdec::maps::bake::Kind::Vector,
            };
            let job = dispdec::app::run::BakeJob { high, base, map, output, resolution, kind, flags: flags(&prep, normals, dmax, None) };
            let r = dispdec::app::run::bake(&job)?;
            say.warnings(&r.warnings);
            say.line(&format!(
                "wrote {} ({} map) and {}: {} of {} texels carry d ({} normals, dmax {:.4}; the pair is {}; {:.1} s)",
                job.output.display(),
                r.kind.name(),
                r.uv_mesh.display(),
                r.defined,
                r.texels,
                if r.normals == NormalMode::Constant { "constant" } else { "interpolated" },
                r.dmax,
                if r.verdict.valid { "valid" } else { "INVALID: the map folds or has holes where the base does" },
                r.seconds
            ));
            say.line(&format!(
                "texels of the charts and gutters: {} from the dense triangle whose image covers them, {} in gaps of the projection (filled from the nearest covered texel of their face where that keeps them on the scan; {} from the nearest crossing instead), {} without d (holes of the scan)",
                r.sources.image, r.sources.gap, r.sources.gap_from_crossing, r.sources.none
            ));
            if let Some(a) = r.agreement {
                say.line(&format!(
                    "against the map's {} vertices: |d difference| RMS {:.3e}, max {:.3e}; {} where the map has no d",
                    a.vertices, a.rms, a.max, a.missing
                ));
            }
            Ok(0)
        }
        Cmd::Reconstruct { base, disp, levels, output, compare, plot, normals } => {
            let (table, warnings) =
                dispdec::app::run::reconstruct(&base, &disp, levels, &output, compare.as_deref(), plot.as_deref(), normals.map(mode_of))?;
            say.warnings(&warnings);
            if !table.is_empty() {
                say.line("level  faces      RMS->scan  Hausdorff->scan  RMS<-scan  Hausdorff<-scan  (fractions of the scan's bbox diagonal)");
                for d in &table {
                    say.line(&format!(
                        "{:>5} {:>8}  {:>10.6}  {:>15.6}  {:>9.6}  {:>15.6}",
                        d.level, d.faces, d.rms_to_scan, d.hausdorff_to_scan, d.rms_from_scan, d.hausdorff_from_scan
                    ));
                }
            }
            say.line(&format!("wrote {}", output.display()));
            Ok(0)
        }
        Cmd::Export { base, disp, output, levels } => {
            let (e, warnings) = dispdec::app::run::export(&base, &disp, &output, levels)?;
            say.warnings(&warnings);
            say.line(&format!(
                "wrote {} ({} bytes: the {}-face base with a {}x{} 16-bit normalized map{})",
                output.display(),
                e.bytes,
                e.base_faces,
                e.texture.size,
                e.texture.size,
                e.rebuilt_faces.map(|f| format!(", and the {f}-face mesh rebuilt at level {}", levels.unwrap_or(0))).unwrap_or_default()
            ));
            Ok(0)
        }
        Cmd::Render { meshes, output, size, yaw, pitch, mark } => {
            let adapter = dispdec::app::run::render(&meshes, mark.as_deref(), &output, dispdec::gpu::render::View { size, yaw, pitch })?;
            say.line(&format!("wrote {} ({} meshes, {adapter})", output.display(), meshes.len()));
            Ok(0)
        }
        Cmd::Bench { json, runs, data, meshes, configs, work, batch, ring_directions } => {
            let data = data
                .or_else(|| std::env::var_os("DISPDEC_DATA").map(PathBuf::from))
                .unwrap_or_else(|| PathBuf::from("../shared/data"));
            let job = dispdec::app::bench::BenchJob {
                data,
                meshes,
                configs: configs.into_iter().map(bench_config).collect(),
                runs,
                work: work.unwrap_or_else(|| std::env::temp_dir().join(format!("dispdec-bench-{}", std::process::id()))),
                exe: std::env::current_exe()?,
                json: json.clone(),
                batch,
                ring: ring_of(ring_directions),
            };
            let report = dispdec::app::bench::bench(&job, |line| say.line(line))?;
            print!("{}", dispdec::app::bench::table(&report));
            if let Some(p) = json {
                let text = serde_json::to_string_pretty(&report)?;
                dispdec::mesh::write_atomic(&p, text.as_bytes())?;
            }
            Ok(0)
        }
        Cmd::ProbeGpu => {
            println!("{}", serde_json::to_string(&dispdec::app::run::ProbeAnswer::here())?);
            Ok(0)
        }
        Cmd::BenchRun { input, output, config, batch, ring_directions, result } => {
            let outcome = dispdec::app::bench::run_one(&input, &output, bench_config(config), batch, ring_of(ring_directions));
            dispdec::mesh::write_atomic(&result, serde_json::to_string(&outcome)?.as_bytes())?;
            Ok(0)
        }
        Cmd::Sample { output, faces, seed } => {
            if !(1_000..=4_000_000).contains(&faces) {
                return Err(dispdec::Error::Usage(format!("--faces must be between 1000 and 4000000, got {faces}")).into());
            }
            let m = dispdec::mesh::sample::generate(dispdec::mesh::sample::SampleSpec { faces, seed });
            let text = dispdec::mesh::sample::to_obj(
                &m,
                &format!("dispdec sample surface: {} faces, seed {seed} (dispdec sample --faces {faces} --seed {seed})", m.faces.len()),
            );
            let bytes = dispdec::mesh::maybe_gzip(&output, text.into_bytes());
            dispdec::mesh::write_atomic(&output, &bytes)?;
            say.line(&format!("wrote {} ({} faces)", output.display(), m.faces.len()));
            Ok(0)
        }
    }
}
