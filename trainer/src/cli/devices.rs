//! `s3tir-train devices`: the Vulkan devices of this computer and what the trainer needs of them.

use anyhow::Result;
use clap::Args;

/// Options of `s3tir-train devices`.
#[derive(Debug, Args)]
pub struct DevicesArgs {
    /// Print one JSON array instead of text.
    #[arg(long)]
    pub json: bool,
}

#[cfg(feature = "vulkan")]
pub fn run(a: &DevicesArgs) -> Result<()> {
    use s3tir_trainer::gpu::VulkanInstance;

    let instance = VulkanInstance::new()?;
    let reports = instance.reports()?;
    if a.json {
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
pub fn run(_: &DevicesArgs) -> Result<()> {
    anyhow::bail!(
        "this s3tir-train was built without the `vulkan` feature: it has no Vulkan backend"
    )
}
