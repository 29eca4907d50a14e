//! The `terrachunk` command: parses the command line and calls the library.

use std::io::IsTerminal;
use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Args, Parser, Subcommand};
use terrachunk::bench;
use terrachunk::config::{Compress, Config, Frame, Mesher, TextureFormat, Thin};
use terrachunk::pipeline::{BuildOptions, Report, build};
use terrachunk::shard;
use terrachunk::texture::TextureSource;
use terrachunk::verify::verify_with_progress;

#[derive(Parser)]
#[command(name = "terrachunk", version, about = "DEM → Chunked-LOD glTF tileset with a 3D Tiles 1.1 index")]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand)]
enum Command {
    /// Build a tileset from a DEM (several .hgt tiles or a folder make a mosaic).
    #[command(allow_negative_numbers = true)]
    Build(BuildArgs),
    /// Plan a sharded build: write a manifest of independent jobs (job 0 the
    /// levels above the shards, then one per block of subtrees) for
    /// `terrachunk build --manifest M --job K`, then `terrachunk merge M`.
    /// Takes `build`'s options; the work folder is OUT.shards unless given.
    #[command(allow_negative_numbers = true)]
    Plan {
        /// How many shard jobs (fewer where the tree has fewer chunks).
        #[arg(long)]
        shards: usize,
        /// Folder for the manifest and the jobs' files [default: OUT.shards].
        #[arg(long)]
        work: Option<PathBuf>,
        #[command(flatten)]
        build: BuildArgs,
    },
    /// Write the tileset of a sharded build whose jobs have all finished:
    /// their chunks and one index over them, byte-identical to `build`'s.
    Merge {
        /// The manifest `terrachunk plan` wrote.
        manifest: PathBuf,
    },
    /// Re-check a tileset from its files: error bounds, borders, morph targets, structure.
    Verify {
        /// Tileset directory.
        dir: PathBuf,
        /// DEM to check against (default: the source named in tileset.json).
        #[arg(long)]
        dem: Vec<PathBuf>,
        /// Geoid model the tileset was built with (default: the one named
        /// in tileset.json, found beside it like the DEM).
        #[arg(long, value_name = "GRID")]
        geoid: Option<PathBuf>,
    },
    /// Print one chunk's level, δ, counts, bounds and morph range.
    Inspect {
        /// A chunk file, e.g. out/tiles/0/0/0.glb.
        glb: PathBuf,
    },
    /// Fly over a tileset in the real-time viewer: runs the `terrachunk-view`
    /// binary (the `viewer/` crate) found next to this one or on PATH, with
    /// the same arguments (`terrachunk view OUT --help` lists them).
    View {
        /// Tileset directory, then any `terrachunk-view` options.
        #[arg(required = true, trailing_var_arg = true, allow_hyphen_values = true)]
        args: Vec<std::ffi::OsString>,
    },
    /// Speed against error: time builds over a ladder of max errors and
    /// measure each result's true error (OUT/bench.csv, bench.png, bench.svg).
    Bench(BenchArgs),
}

#[derive(Args)]
struct BuildArgs {
    /// DEM file(s): GeoTIFF, PNG (16/8-bit gray, Terrain-RGB), .hgt, .asc, .bt, .exr, .vrt (GeoTIFF mosaic).
    #[arg(required_unless_present = "manifest")]
    dem: Vec<PathBuf>,
    /// Output directory.
    #[arg(short, long, required_unless_present = "manifest")]
    out: Option<PathBuf>,
    /// Run one job of a sharded build's manifest (`terrachunk plan`) instead;
    /// only `--threads` applies, every other setting is the manifest's.
    #[arg(long, requires = "job", conflicts_with_all = ["dem", "out", "config"])]
    manifest: Option<PathBuf>,
    /// The job to run: 0 for the levels above the shards, 1… for the shards.
    #[arg(long, requires = "manifest")]
    job: Option<usize>,
    /// Settings file (see pipeline.toml); command-line values win.
    #[arg(long)]
    config: Option<PathBuf>,
    /// Leaf accuracy: largest vertical error of the finest level, metres.
    #[arg(long)]
    max_error: Option<f64>,
    /// Largest screen-space error the runtime may use, pixels.
    #[arg(long)]
    tau_max: Option<f64>,
    /// Worker threads (0 = one per core).
    #[arg(long)]
    threads: Option<usize>,
    /// Most memory the build may hold: 2GB (default), 256MB, 1.5GiB or
    /// none; larger grids go through scratch files beside OUT, same bytes.
    #[arg(long)]
    memory_limit: Option<String>,
    /// Multiply heights by this.
    #[arg(long)]
    vertical_scale: Option<f64>,
    /// Ground spacing in metres: `S` or `SX,SZ`.
    #[arg(long, value_parser = parse_spacing)]
    spacing: Option<[f64; 2]>,
    /// Geoid model (.gtx or geographic GeoTIFF, e.g. PROJ's egm96_15) whose
    /// undulation makes heights ellipsoidal [default: heights as given].
    #[arg(long, value_name = "GRID")]
    geoid: Option<PathBuf>,
    /// Colour image for the chunks (PNG, JPEG, 8-bit GeoTIFF), or `none`
    /// for untextured chunks [default: a hillshade generated from the DEM].
    #[arg(long, value_name = "IMAGE|none")]
    texture: Option<String>,
    /// How texture tiles are stored in the .glb.
    #[arg(long, value_enum)]
    texture_format: Option<TextureFormat>,
    /// JPEG quality, 1..=100.
    #[arg(long)]
    jpeg_quality: Option<u8>,
    /// Widest texture tile, texels.
    #[arg(long)]
    max_texture_px: Option<u32>,
    /// Most tiles one index file holds; a larger tree's subtrees go into
    /// external tilesets beside tileset.json [default: 16384].
    #[arg(long)]
    index_tiles: Option<usize>,
    /// Also write a tangent-space normal map from the full-resolution DEM.
    #[arg(long)]
    normal_map: bool,
    /// Widest a deepest-level chunk may be, in cells, 2..=4096 [default:
    /// chosen from the data]. Wider leaves make a smaller tileset with
    /// fewer leaf triangles but cull in bigger pieces (docs/settings.md, "Chunk size").
    #[arg(long)]
    leaf_cells: Option<u32>,
    /// Widest a top-level chunk may be, in cells, 2..=65536 [default:
    /// one top-level chunk]. Narrower top chunks make a tree with fewer
    /// levels: fewer leaf triangles and a smaller tileset, but a far view
    /// that draws every top chunk (docs/settings.md, "Top-level chunks").
    #[arg(long)]
    root_cells: Option<u32>,
    /// Most surface vertices one chunk may hold, 65535..=16777215
    /// [default: 65535]; denser coarse chunks make the build add
    /// refine levels. Chunks over 65 535 vertices get u32 indices.
    #[arg(long)]
    max_chunk_vertices: Option<u32>,
    /// Which levels the mesher thins after greedy insertion: `leaves`
    /// (the deepest), `all` (fewer triangles, slower), or `none`
    /// [default: leaves].
    #[arg(long, value_enum)]
    thin: Option<Thin>,
    /// Which mesher makes the chunks: `rtin` (right-triangle bintree,
    /// no slivers) or `tin` (greedy insertion, fewer triangles, slivers on
    /// flat ground) [default: rtin].
    #[arg(long, value_enum)]
    mesher: Option<Mesher>,
    /// The frame of a georeferenced grid's chunks: `flat` (the tangent
    /// plane at the centre), `curved` (every vertex at its WGS 84 position)
    /// or `auto` (curved where flat would miss by over max-error/4)
    /// [default: auto].
    #[arg(long, value_enum)]
    frame: Option<Frame>,
    /// Build every chunk to the deepest level, even below one that already
    /// meets the error (to measure what the error-bounded tree saves).
    #[arg(long)]
    complete_tree: bool,
    /// How vertex data is stored: f32 (`none`, opens everywhere),
    /// KHR_mesh_quantization (`quantize`), that plus
    /// EXT_meshopt_compression (`meshopt`, for every meshopt reader) or
    /// plus KHR_meshopt_compression with meshoptimizer's v1 vertex codec
    /// (`meshopt-v1`, the smallest; CesiumJS ≥ 1.143) [default: none].
    #[arg(long, value_enum)]
    compress: Option<Compress>,
    /// Replace an existing output directory.
    #[arg(long)]
    force: bool,
    /// Also write the summary as JSON here.
    #[arg(long)]
    report: Option<PathBuf>,
}

#[derive(Args)]
#[command(group = clap::ArgGroup::new("mode").multiple(false))]
struct BenchArgs {
    /// DEM file(s), each benchmarked on its own.
    #[arg(required_unless_present = "replot")]
    dem: Vec<PathBuf>,
    /// max_error_m values, metres [default: 0.25,0.5,1,2,5,10,20; with --scale: 1].
    #[arg(long, value_delimiter = ',')]
    errors: Option<Vec<f64>>,
    /// Timed runs per configuration; the CSV holds their medians.
    #[arg(long, default_value_t = 3)]
    runs: usize,
    /// Untimed runs before the timed ones.
    #[arg(long, default_value_t = 1)]
    warmup: usize,
    /// Thread counts (0 = one per core) [default: 0; with --scale: 1,2].
    #[arg(long, value_delimiter = ',')]
    threads: Option<Vec<usize>>,
    /// Output folder.
    #[arg(short, long, default_value = "bench-out")]
    out: PathBuf,
    /// Settings file for every build (see pipeline.toml).
    #[arg(long)]
    config: Option<PathBuf>,
    /// Use the top-left N × N samples, repeating the last row or column where
    /// the grid is smaller (pymartini needs N = 2^k + 1).
    #[arg(long, value_name = "N")]
    square: Option<usize>,
    /// Also time one unconstrained greedy TIN over the grid (terrachunk-single-tin).
    #[arg(long)]
    single_tin: bool,
    /// Add rows to OUT/bench.csv instead of starting it anew.
    #[arg(long)]
    append: bool,
    /// Scaling: centred windows with 1/F of the samples each, e.g. 16,4,1
    /// (OUT/scaling.csv).
    #[arg(long, value_delimiter = ',', value_name = "F,...", group = "mode", conflicts_with_all = ["square", "single_tin"])]
    scale: Option<Vec<u32>>,
    /// Write the grid (after --square) as a float32 .npy file and stop.
    #[arg(long, value_name = "FILE", group = "mode")]
    export_grid: Option<PathBuf>,
    /// Measure an OBJ mesh (column, height, row in grid units) against the
    /// grid and print its errors as JSON.
    #[arg(long, value_name = "FILE", group = "mode")]
    measure_mesh: Option<PathBuf>,
    /// Add other tools' meshes, listed in a CSV (tool,max_error_m,seconds,runs,mesh),
    /// measured against the grid, to OUT/bench.csv.
    #[arg(long, value_name = "MANIFEST", group = "mode")]
    peers: Option<PathBuf>,
    /// Redraw OUT/bench.png and OUT/bench.svg from OUT/bench.csv.
    #[arg(long, group = "mode")]
    replot: bool,
    /// Build each DEM as shipped and as a complete tree (every chunk to the
    /// deepest level) at each error; compare chunks, triangles and bytes
    /// (OUT/savings.csv, and a Markdown table on stdout) [default errors: 1].
    #[arg(long, group = "mode", conflicts_with_all = ["square", "single_tin"])]
    savings: bool,
}

fn parse_spacing(s: &str) -> Result<[f64; 2], String> {
    let v: Vec<f64> =
        s.split(',').map(|p| p.trim().parse::<f64>()).collect::<Result<_, _>>().map_err(|e| e.to_string())?;
    match v.as_slice() {
        [a] => Ok([*a, *a]),
        [a, b] => Ok([*a, *b]),
        _ => Err("expected S or SX,SZ".into()),
    }
}

fn main() -> ExitCode {
    let cli = Cli::parse();
    match run(cli) {
        Ok(code) => code,
        Err(e) => {
            eprintln!("error: {e:#}");
            ExitCode::from(2)
        }
    }
}

fn run(cli: Cli) -> anyhow::Result<ExitCode> {
    match cli.command {
        Command::Build(args) => {
            if let (Some(manifest), Some(job)) = (&args.manifest, args.job) {
                return Ok(match shard::run_job(manifest, job, args.threads) {
                    Ok(r) => {
                        match (&r.report, r.already_done) {
                            (_, true) => println!("job {job}: already done"),
                            (Some(rep), false) => println!(
                                "job {job}: {} chunks in {:.2} s{}",
                                r.chunks,
                                r.seconds,
                                rep.peak_rss_bytes
                                    .map_or(String::new(), |b| format!(", peak memory {:.1} MB", b as f64 / 1e6))
                            ),
                            (None, false) => println!("job {job}: {} chunks", r.chunks),
                        }
                        ExitCode::SUCCESS
                    }
                    Err(e) => {
                        eprintln!("error: {e}");
                        ExitCode::from(e.exit_code() as u8)
                    }
                });
            }
            let (opts, report) = match build_options(args) {
                Ok(o) => o,
                Err(e) => {
                    eprintln!("error: {e}");
                    return Ok(ExitCode::from(2));
                }
            };
            if let Some(p) = &report
                && let Err(e) = Report::check_path(p, &opts.inputs)
            {
                eprintln!("error: {e}");
                return Ok(ExitCode::from(2));
            }
            let out = opts.out.clone();
            match build(&opts) {
                Ok(r) => {
                    print!("{}", r.summary(&out, opts.config.max_chunk_vertices));
                    if let Some(warning) = r.over_delta_warning() {
                        eprintln!("{warning}");
                    }
                    if let Some(warning) = r.flat_frame_warning() {
                        eprintln!("{warning}");
                    }
                    if let Some(warning) = r.not_placed_warning() {
                        eprintln!("{warning}");
                    }
                    if let Some(p) = report
                        && let Err(e) = r.write(&p)
                    {
                        // The tileset is in place: not exit 2, which says nothing was written.
                        eprintln!("error: {e} (the tileset itself is complete in {})", out.display());
                        return Ok(ExitCode::from(1));
                    }
                    Ok(ExitCode::SUCCESS)
                }
                Err(e) => {
                    eprintln!("error: {e}");
                    Ok(ExitCode::from(e.exit_code() as u8))
                }
            }
        }
        Command::Plan { shards, work, build } => {
            if build.manifest.is_some() {
                eprintln!("error: `plan` takes DEM files and build options, not --manifest");
                return Ok(ExitCode::from(2));
            }
            let (opts, _) = match build_options(build) {
                Ok(o) => o,
                Err(e) => {
                    eprintln!("error: {e}");
                    return Ok(ExitCode::from(2));
                }
            };
            let work = work.unwrap_or_else(|| shard::default_work(&opts.out));
            match shard::plan(&opts, shards, &work) {
                Ok(path) => {
                    let m = shard::read_manifest(&path)?;
                    println!(
                        "{}: {} jobs (job 0: the levels above {}; {} shard jobs from level {} down)",
                        path.display(),
                        m.jobs.len(),
                        m.shard_level,
                        m.jobs.len() - 1,
                        m.shard_level
                    );
                    Ok(ExitCode::SUCCESS)
                }
                Err(e) => {
                    eprintln!("error: {e}");
                    Ok(ExitCode::from(e.exit_code() as u8))
                }
            }
        }
        Command::Merge { manifest } => match shard::merge(&manifest) {
            Ok(m) => {
                println!(
                    "{}: {} chunks, index {} bytes in {} file(s)",
                    m.out.display(),
                    m.chunks,
                    m.index_bytes,
                    m.index_files
                );
                Ok(ExitCode::SUCCESS)
            }
            Err(e) => {
                eprintln!("error: {e}");
                Ok(ExitCode::from(e.exit_code() as u8))
            }
        },
        Command::Verify { dir, dem, geoid } => {
            let over = (!dem.is_empty()).then_some(dem.as_slice());
            let r = match verify_with_progress(&dir, over, geoid.as_deref(), std::io::stderr().is_terminal()) {
                Ok(r) => r,
                Err(e) => {
                    eprintln!("error: {e}");
                    return Ok(ExitCode::from(2));
                }
            };
            print!("{r}");
            Ok(if r.failures.is_empty() { ExitCode::SUCCESS } else { ExitCode::from(1) })
        }
        Command::View { args } => view(&args),
        Command::Inspect { glb } => match terrachunk::verify::inspect(&glb) {
            Ok(i) => {
                print!("{i}");
                Ok(ExitCode::SUCCESS)
            }
            Err(e) => {
                eprintln!("error: {e}");
                Ok(ExitCode::from(2))
            }
        },
        Command::Bench(args) => {
            let out = args.out.clone();
            let made = !out.exists();
            match run_bench(args) {
                Ok(()) => Ok(ExitCode::SUCCESS),
                Err(e) => {
                    eprintln!("error: {e}");
                    if made {
                        // Only an empty folder goes: whatever was written stays.
                        let _ = std::fs::remove_dir(&out);
                    }
                    Ok(ExitCode::from(e.exit_code() as u8))
                }
            }
        }
    }
}

/// The build options the command line gives, with the file it wants the
/// report in: settings file first, command-line values over it.
fn build_options(a: BuildArgs) -> Result<(BuildOptions, Option<PathBuf>), String> {
    let BuildArgs {
        dem,
        out,
        manifest: _,
        job: _,
        config,
        max_error,
        tau_max,
        threads,
        memory_limit,
        vertical_scale,
        spacing,
        geoid,
        texture,
        texture_format,
        jpeg_quality,
        max_texture_px,
        index_tiles,
        normal_map,
        leaf_cells,
        root_cells,
        max_chunk_vertices,
        thin,
        mesher,
        frame,
        complete_tree,
        compress,
        force,
        report,
    } = a;
    let mut cfg = match &config {
        Some(p) => Config::from_file(p).map_err(|e| e.to_string())?,
        None => Config::default(),
    };
    if let Some(v) = max_error {
        cfg.max_error_m = v;
    }
    if let Some(v) = tau_max {
        cfg.tau_max_px = v;
    }
    if let Some(v) = threads {
        cfg.threads = v;
    }
    if let Some(v) = memory_limit {
        cfg.memory_limit = v;
    }
    if let Some(v) = vertical_scale {
        cfg.vertical_scale = v;
    }
    if spacing.is_some() {
        cfg.spacing_m = spacing;
    }
    if let Some(f) = texture_format {
        cfg.texture_format = f;
    }
    if let Some(v) = jpeg_quality {
        cfg.jpeg_quality = v;
    }
    if let Some(v) = max_texture_px {
        cfg.max_texture_px = v;
    }
    if let Some(v) = index_tiles {
        cfg.index_tiles = v;
    }
    cfg.normal_map |= normal_map;
    if leaf_cells.is_some() {
        cfg.leaf_cells = leaf_cells;
    }
    if root_cells.is_some() {
        cfg.root_cells = root_cells;
    }
    if let Some(v) = max_chunk_vertices {
        cfg.max_chunk_vertices = v;
    }
    if let Some(t) = thin {
        cfg.thin = t;
    }
    if let Some(m) = mesher {
        cfg.mesher = m;
    }
    if let Some(f) = frame {
        cfg.frame = f;
    }
    cfg.complete_tree |= complete_tree;
    if let Some(c) = compress {
        cfg.compress = c;
    }
    let opts = BuildOptions {
        inputs: dem,
        out: out.ok_or("give -o OUT")?,
        force,
        config: cfg,
        texture: texture.as_deref().map_or(TextureSource::Generated, TextureSource::from_arg),
        progress: std::io::stderr().is_terminal(),
        geoid,
    };
    Ok((opts, report))
}

/// Runs the sibling `terrachunk-view` binary: the viewer is its own crate so
/// that this one builds and tests without a GPU stack.
fn view(args: &[std::ffi::OsString]) -> anyhow::Result<ExitCode> {
    let name = format!("terrachunk-view{}", std::env::consts::EXE_SUFFIX);
    let sibling = std::env::current_exe().ok().and_then(|e| e.parent().map(|d| d.join(&name)));
    let program = match &sibling {
        Some(p) if p.is_file() => p.clone(),
        _ => PathBuf::from(&name),
    };
    match std::process::Command::new(&program).args(args).status() {
        Ok(status) => Ok(ExitCode::from(status.code().map_or(1, |c| c.clamp(0, 255) as u8))),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => anyhow::bail!(
            "`terrachunk view` needs the `{name}` binary, next to this one ({}) or on PATH: \
             build it with `cargo build -p terrachunk-view` or install it with \
             `cargo install --path viewer`",
            sibling.map_or_else(|| "?".into(), |p| p.display().to_string())
        ),
        Err(e) => Err(anyhow::Error::new(e).context(format!("running {}", program.display()))),
    }
}

fn run_bench(a: BenchArgs) -> Result<(), bench::BenchError> {
    let cut = a.square.map_or(bench::Cut::Whole, bench::Cut::Square);
    let config = a.config.as_deref();
    let one_dem = || match a.dem.as_slice() {
        [d] => Ok(d.as_path()),
        _ => Err(bench::BenchError::Usage("give exactly one DEM with --export-grid, --measure-mesh or --peers".into())),
    };
    let exe = || std::env::current_exe().map_err(|source| bench::BenchError::Io { path: "terrachunk".into(), source });
    if a.replot {
        bench::replot(&a.out)?;
        println!("{}", a.out.join("bench.png").display());
    } else if let Some(npy) = &a.export_grid {
        let (label, hf) = bench::export_grid(one_dem()?, cut, config, npy)?;
        let nodata = hf.heights.len() - hf.valid_count();
        println!("{}: {} × {} float32 ({nodata} nodata as NaN) from {label}", npy.display(), hf.width, hf.height);
    } else if let Some(obj) = &a.measure_mesh {
        let (_, hf) = bench::cut_grid(one_dem()?, cut, &bench::load_options(config)?)?;
        let m = bench::measure_mesh(&hf, obj)?;
        println!("{}", serde_json::to_string_pretty(&m).expect("plain values"));
    } else if let Some(manifest) = &a.peers {
        let rows = bench::import_peers(one_dem()?, cut, config, manifest, &a.out)?;
        println!("{} rows added to {}", rows.len(), a.out.join("bench.csv").display());
    } else {
        let runs = |errors: Vec<f64>, threads: Vec<usize>| -> Result<bench::Runs, bench::BenchError> {
            Ok(bench::Runs {
                exe: exe()?,
                dems: a.dem.clone(),
                errors: a.errors.clone().unwrap_or(errors),
                runs: a.runs,
                warmup: a.warmup,
                threads: a.threads.clone().unwrap_or(threads),
                out: a.out.clone(),
                config: a.config.clone(),
            })
        };
        if a.savings {
            let rows = bench::savings::savings(&runs(vec![1.0], vec![0])?)?;
            print!("{}", bench::savings::markdown(&rows));
            println!("{}", a.out.join("savings.csv").display());
        } else if let Some(fractions) = a.scale.clone() {
            let rows = bench::scaling(&bench::ScaleOptions { base: runs(vec![1.0], vec![1, 2])?, fractions })?;
            print!("{}", bench::scaling_summary(&rows));
            println!("{}", a.out.join("scaling.csv").display());
        } else {
            let rows = bench::ladder(&bench::LadderOptions {
                base: runs(vec![0.25, 0.5, 1.0, 2.0, 5.0, 10.0, 20.0], vec![0])?,
                cut,
                single_tin: a.single_tin,
                append: a.append,
            })?;
            print_bench(&rows);
            println!("{}", a.out.join("bench.csv").display());
        }
    }
    Ok(())
}

fn print_bench(rows: &[bench::table::Row]) {
    println!(
        "{:<22} {:<30} {:>8} {:>11} {:>11} {:>10} {:>10} {:>9}",
        "tool", "dem", "max err", "leaf tris", "all tris", "meas. max", "meas. RMS", "seconds"
    );
    let o = |v: Option<usize>| v.map(|v| v.to_string()).unwrap_or_default();
    for r in rows {
        println!(
            "{:<22} {:<30} {:>8} {:>11} {:>11} {:>10.4} {:>10.4} {:>9.3}",
            r.tool,
            r.dem,
            r.max_error_m,
            o(r.leaf_triangles),
            o(r.triangles),
            r.measured_max_error_m.unwrap_or(f64::NAN),
            r.measured_rms_error_m.unwrap_or(f64::NAN),
            r.total_seconds().unwrap_or(f64::NAN)
        );
    }
}
