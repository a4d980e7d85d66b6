//! `s3tir-train bench`: training steps/s of the Vulkan and CPU backends, (`--mesh`) the stages
//! of meshing, or (`--lpips`) what LPIPS adds to an evaluation.

use anyhow::Result;
#[cfg(not(feature = "vulkan"))]
use anyhow::bail;
use clap::Args;

/// Options of `s3tir-train bench`.
#[derive(Debug, Args)]
pub struct BenchArgs {
    /// Print one JSON object (`cpu_steps_per_s`, `vulkan_steps_per_s`, `s3tir_steps_per_s`,
    /// `gaussian_steps_per_s`, `device`, ratios, `kernels`).
    #[arg(long)]
    json: bool,
    /// Image width of the benchmark scene [default: 96; --mesh: 640].
    #[arg(long)]
    width: Option<usize>,
    /// Image height of the benchmark scene [default: 72; --mesh: 512].
    #[arg(long)]
    height: Option<usize>,
    /// Views of the benchmark scene [default: 12; --mesh: 100].
    #[arg(long)]
    views: Option<usize>,
    /// Primitives (constant: densification off) [default: 2000; --mesh: 30000].
    #[arg(long)]
    primitives: Option<usize>,
    /// Timed training steps per configuration. They run in rounds of at most 5 steps, the
    /// configurations taking turns, so a slow spell of the machine falls on all of them alike.
    #[arg(long, default_value_t = 20)]
    steps: usize,
    /// Untimed steps first (pipeline compilation, buffer growth).
    #[arg(long, default_value_t = 3)]
    warmup_steps: usize,
    /// Vulkan device (position in `s3tir-train devices`).
    #[arg(long)]
    device_index: Option<usize>,
    /// Force the compare-and-swap fallback instead of float atomics.
    #[arg(long)]
    no_float_atomics: bool,
    /// The realistic configuration instead of the small default scene: 320×256, 24 views,
    /// 30 000 primitives, 10 timed steps (a real thermal scene trained at half resolution;
    /// overrides --width, --height, --views, --primitives and --steps).
    #[arg(long)]
    real_size: bool,
    /// The s3tir configurations with only this fraction of the primitives holding bands, spread
    /// evenly, the others band-free and back on the Gaussian path: the state the band grant
    /// and the next capacity check leave (capacity.json's `band_holders` over `primitives` of
    /// a run). 1: every primitive holds M bands; 0: none, a scene like the real facade at its
    /// end (no band, every β at 2: the spectral terms off, as in the run).
    #[arg(long, default_value_t = 1.0)]
    band_holders: f64,
    /// Benchmark `mesh` instead of training: seconds per stage (render, fuse, extract) and
    /// peak memory of meshing 100 views of 640×512 with 30 000 primitives on the CPU backend
    /// (--width, --height, --views, --primitives change it).
    #[arg(long, conflicts_with = "lpips")]
    mesh: bool,
    /// Benchmark LPIPS in evaluations instead of training: milliseconds per held-out view of
    /// 640×512 (first evaluation: the network on render and frame; later ones: on the render,
    /// the frame's features kept) against the CPU render of the same view with 30 000
    /// primitives (--width, --height, --views, --primitives change it).
    #[arg(long)]
    lpips: bool,
}

/// `bench`: the training benchmark, or the mesh benchmark with `--mesh`.
pub fn run(a: &BenchArgs) -> Result<()> {
    if a.mesh {
        mesh_bench_cmd(a)
    } else if a.lpips {
        lpips_bench_cmd(a)
    } else {
        bench_cmd(a)
    }
}

#[cfg(feature = "vulkan")]
fn bench_cmd(a: &BenchArgs) -> Result<()> {
    use s3tir_trainer::gpu::bench::{self, BenchOptions};
    let (width, height, views, primitives, steps) = if a.real_size {
        (320, 256, 24, 30_000, 10)
    } else {
        (
            a.width.unwrap_or(96),
            a.height.unwrap_or(72),
            a.views.unwrap_or(12),
            a.primitives.unwrap_or(2000),
            a.steps,
        )
    };
    let opts = BenchOptions {
        width,
        height,
        views,
        primitives,
        steps,
        warmup_steps: a.warmup_steps,
        band_holders: a.band_holders,
        device: super::vulkan_options(a.device_index, a.no_float_atomics),
    };
    let r = bench::run(&opts, &mut |line| eprintln!("bench: {line}"))?;
    if a.json {
        println!("{}", serde_json::to_string(&r)?);
        return Ok(());
    }
    println!(
        "device {}; scene {}x{}, {} primitives ({:.0} % holding bands in s3tir mode), {} timed steps per configuration",
        r.device,
        r.width,
        r.height,
        r.primitives,
        100.0 * r.band_holders,
        r.steps
    );
    println!(
        "  CPU backend, s3tir mode     {:8.2} steps/s on {} threads, {:.2} on one ({:.2}x)",
        r.cpu_steps_per_s, r.cpu_threads, r.cpu_one_thread_steps_per_s, r.cpu_parallel_speedup
    );
    println!(
        "  Vulkan backend, s3tir mode  {:8.2} steps/s",
        r.s3tir_steps_per_s
    );
    println!(
        "  Vulkan backend, 3dgs mode   {:8.2} steps/s",
        r.gaussian_steps_per_s
    );
    println!(
        "  Vulkan / CPU                {:8.2}x  (goal >= 3)",
        r.vulkan_speedup_over_cpu
    );
    println!(
        "  s3tir cost / 3dgs           {:8.2}x  (goal <= 1.5)",
        r.s3tir_cost_over_gaussian
    );
    println!(
        "  s3tir, partner rendered     {:8.2} steps/s, {:.2}x 3dgs  (--consist-partner render)",
        r.s3tir_render_partner_steps_per_s, r.s3tir_render_partner_cost_over_gaussian
    );
    println!(
        "  process CPU time per step: CPU backend {:.1} ms, Vulkan s3tir {:.1} ms, Vulkan 3dgs {:.1} ms",
        r.cpu_backend_cpu_ms_per_step, r.vulkan_cpu_ms_per_step, r.gaussian_cpu_ms_per_step
    );
    println!(
        "  peak GPU memory             {:8.1} MiB",
        r.peak_gpu_bytes as f64 / (1024.0 * 1024.0)
    );
    println!(
        "  host reads per step         {:8.1} ({:.0} bytes; {:.1} submissions), Vulkan s3tir",
        r.host_reads_per_step, r.host_read_bytes_per_step, r.submissions_per_step
    );
    println!("  {}", r.joint_line());
    println!("  GPU time (dispatches) per step:  s3tir mode              3dgs mode");
    for k in &r.kernels {
        println!(
            "    {:<26} {:8.3} ms ({:4.1}) {:5.1} %  {:8.3} ms ({:4.1})",
            k.kernel,
            k.ms_per_step,
            k.dispatches_per_step,
            100.0 * k.share,
            k.gaussian_ms_per_step,
            k.gaussian_dispatches_per_step
        );
    }
    let total = |f: fn(&bench::KernelShare) -> f64| r.kernels.iter().map(f).sum::<f64>();
    println!(
        "    {:<26} {:8.3} ms ({:4.1})          {:8.3} ms ({:4.1})",
        "all kernels",
        total(|k| k.ms_per_step),
        total(|k| k.dispatches_per_step),
        total(|k| k.gaussian_ms_per_step),
        total(|k| k.gaussian_dispatches_per_step)
    );
    Ok(())
}

#[cfg(not(feature = "vulkan"))]
fn bench_cmd(_: &BenchArgs) -> Result<()> {
    bail!(
        "this s3tir-train was built without the `vulkan` feature: there is nothing to compare the CPU with"
    )
}

/// `bench --lpips`: LPIPS's cost per view (see `s3tir_trainer::lpips::bench`).
fn lpips_bench_cmd(a: &BenchArgs) -> Result<()> {
    let lpips = s3tir_trainer::lpips::Lpips::load_installed()?;
    let size = (
        a.width.unwrap_or(640),
        a.height.unwrap_or(512),
        a.views.unwrap_or(12),
        a.primitives.unwrap_or(30_000),
    );
    let r = s3tir_trainer::lpips::bench::run(&lpips, size, &mut |line| eprintln!("bench: {line}"))?;
    if a.json {
        println!("{}", serde_json::to_string(&r)?);
        return Ok(());
    }
    println!(
        "lpips: {} views of {}x{}, {} primitives, {} threads",
        r.views, r.width, r.height, r.primitives, r.threads
    );
    println!(
        "  CPU render {:.1} ms/view; LPIPS first evaluation {:.1} ms/view ({:.2}x the render), \
         later evaluations {:.1} ms/view ({:.2}x)",
        r.render_ms, r.lpips_first_ms, r.first_over_render, r.lpips_cached_ms, r.cached_over_render
    );
    Ok(())
}

/// `bench --mesh`: the mesh benchmark (see `s3tir_trainer::mesh::bench`).
fn mesh_bench_cmd(a: &BenchArgs) -> Result<()> {
    use s3tir_trainer::mesh::bench::{MeshBenchOptions, run};
    let d = MeshBenchOptions::default();
    let opts = MeshBenchOptions {
        width: a.width.unwrap_or(d.width),
        height: a.height.unwrap_or(d.height),
        views: a.views.unwrap_or(d.views),
        primitives: a.primitives.unwrap_or(d.primitives),
        ..d
    };
    let r = run(&opts, &mut |_, _, _| {}, &mut |line| {
        eprintln!("bench: {line}")
    })?;
    if a.json {
        println!("{}", serde_json::to_string(&r)?);
        return Ok(());
    }
    let mib = |b: Option<u64>| {
        b.map_or_else(
            || "unknown".to_owned(),
            |b| format!("{:.0} MiB", b as f64 / f64::from(1 << 20)),
        )
    };
    let st = &r.stats;
    println!(
        "mesh: {} views of {}x{}, {} primitives, CPU backend on {} threads",
        st.views_rendered, r.width, r.height, r.primitives, r.threads
    );
    println!(
        "  render {:.1} s, fuse {:.1} s ({:.2}x the render), extract {:.1} s ({:.2}x); total {:.1} s",
        st.render_s, st.fuse_s, r.fuse_over_render, st.extract_s, r.extract_over_render, r.seconds
    );
    println!(
        "  voxel {:.2} mm, {} blocks: volume {:.0} MiB, renders kept {:.0} MiB; peak memory {} (before meshing {})",
        st.voxel_m * 1e3,
        st.blocks,
        st.volume_bytes as f64 / f64::from(1 << 20),
        st.renders_bytes as f64 / f64::from(1 << 20),
        mib(r.peak_rss_bytes),
        mib(r.rss_before_bytes)
    );
    println!("  {} vertices, {} triangles", st.vertices, st.triangles);
    Ok(())
}
