//! `s3tir-train`: S³-TIR thermal splatting on the rig.

use anyhow::Result;
use clap::{Parser, Subcommand};

/// S³-TIR thermal splatting: fit spatial-spectral primitives to posed thermal (and RGB) frames
/// with a Vulkan compute trainer that runs on the rig, and render novel views.
///
/// `devices` lists the Vulkan devices this computer offers and what the trainer needs of them
/// (storage-buffer range, shared memory, subgroups, float atomics).
#[derive(Debug, Parser)]
#[command(name = "s3tir-train", version, about, long_about)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// List Vulkan devices: name, driver, API version, memory heaps, max storage-buffer range,
    /// shared memory, subgroup size and operations, float-atomic support. Exits non-zero with
    /// the reason when no Vulkan loader or driver is present.
    Devices {
        /// Print one JSON array instead of text.
        #[arg(long)]
        json: bool,
    },
}

fn main() -> Result<()> {
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_default_env().unwrap_or_else(|_| "warn".into()),
        )
        .with_writer(std::io::stderr)
        .init();
    match Cli::parse().command {
        Command::Devices { json } => devices(json),
    }
}

#[cfg(feature = "vulkan")]
fn devices(json: bool) -> Result<()> {
    use s3tir_trainer::gpu::VulkanInstance;

    let instance = VulkanInstance::new()?;
    let reports = instance.reports()?;
    if json {
        println!("{}", serde_json::to_string_pretty(&reports)?);
        return Ok(());
    }
    const MIB: f64 = 1024.0 * 1024.0;
    for r in &reports {
        println!("[{}] {} ({})", r.index, r.name, r.device_type);
        println!("    driver            {} {}", r.driver_name, r.driver_info);
        println!("    Vulkan API        {}", r.api_version);
        for (i, h) in r.memory_heaps.iter().enumerate() {
            let local = if h.device_local {
                "device-local"
            } else {
                "host"
            };
            println!(
                "    memory heap {i}     {:.0} MiB ({local})",
                h.size_bytes as f64 / MIB
            );
        }
        println!(
            "    storage buffer    max range {:.0} MiB",
            r.max_storage_buffer_range_bytes as f64 / MIB
        );
        println!(
            "    compute           {} KiB shared memory, {} invocations per workgroup",
            r.max_compute_shared_memory_bytes / 1024,
            r.max_compute_workgroup_invocations
        );
        println!(
            "    subgroups         size {}, {} ({})",
            r.subgroup_size,
            r.subgroup_operations.join(" "),
            if r.subgroup_in_compute {
                "in compute"
            } else {
                "NOT in compute"
            }
        );
        let yn = |b: bool| if b { "yes" } else { "no" };
        println!(
            "    float atomics     buffer add {}, shared add {}{}",
            yn(r.float_atomics.buffer_f32_add),
            yn(r.float_atomics.shared_f32_add),
            if r.float_atomics.buffer_f32_add {
                ""
            } else {
                " (kernels use the CAS/reduction fallback)"
            }
        );
        println!(
            "    timestamps        {}",
            if r.compute_timestamp_bits > 0 {
                format!(
                    "{} bits, {} ns/tick",
                    r.compute_timestamp_bits, r.timestamp_period_ns
                )
            } else {
                "not on compute queues".to_owned()
            }
        );
    }
    Ok(())
}

#[cfg(not(feature = "vulkan"))]
fn devices(_json: bool) -> Result<()> {
    anyhow::bail!(
        "this s3tir-train was built without the `vulkan` feature: it has no Vulkan backend"
    )
}
