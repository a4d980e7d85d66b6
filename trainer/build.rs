//! Compiles every GLSL compute shader in `shaders/` to SPIR-V with Debian's `glslc` (feature
//! `vulkan` only) and generates `shaders.rs`, a table of (name, SPIR-V bytes) the crate embeds.
//!
//! `glslc` rejects invalid GLSL at build time, so a broken shader fails the build; the test
//! `every_shader_builds_a_pipeline` then creates a pipeline from each on a real driver.

use std::env;
use std::fmt::Write as _;
use std::fs;
use std::path::{Path, PathBuf};
use std::process::Command;

fn main() {
    println!("cargo:rerun-if-changed=shaders");
    println!("cargo:rerun-if-env-changed=GLSLC");
    if env::var_os("CARGO_FEATURE_VULKAN").is_none() {
        return;
    }
    let out_dir =
        PathBuf::from(env::var("OUT_DIR").unwrap_or_else(|_| fail("OUT_DIR not set by cargo")));
    let glslc = env::var("GLSLC").unwrap_or_else(|_| "glslc".to_owned());
    let shader_dir = Path::new("shaders");
    let mut sources: Vec<PathBuf> = fs::read_dir(shader_dir)
        .unwrap_or_else(|e| fail(&format!("cannot read {}: {e}", shader_dir.display())))
        .filter_map(|entry| entry.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "comp"))
        .collect();
    sources.sort();

    let mut table = String::from(
        "/// Every compute shader of `shaders/`, compiled by glslc: (name, SPIR-V bytes).\npub static SHADERS: &[(&str, &[u8])] = &[\n",
    );
    for src in &sources {
        println!("cargo:rerun-if-changed={}", src.display());
        let stem = src
            .file_stem()
            .and_then(|s| s.to_str())
            .unwrap_or_else(|| fail(&format!("shader name {} is not UTF-8", src.display())));
        let spv = out_dir.join(format!("{stem}.spv"));
        let output = Command::new(&glslc)
            .args(["--target-env=vulkan1.2", "-O", "-Werror", "-I"])
            .arg(shader_dir)
            .arg("-o")
            .arg(&spv)
            .arg(src)
            .output()
            .unwrap_or_else(|e| {
                fail(&format!(
                    "cannot run `{glslc}` ({e}). Install Debian's `glslc` package \
                     (scripts/install-deps.sh does), set GLSLC to its path, or build without \
                     the `vulkan` feature (--no-default-features)"
                ))
            });
        if !output.status.success() {
            fail(&format!(
                "glslc failed on {}:\n{}",
                src.display(),
                String::from_utf8_lossy(&output.stderr)
            ));
        }
        let _ = writeln!(
            table,
            "    ({stem:?}, include_bytes!({:?})),",
            spv.display().to_string()
        );
    }
    table.push_str("];\n");
    let table_path = out_dir.join("shaders.rs");
    fs::write(&table_path, table)
        .unwrap_or_else(|e| fail(&format!("cannot write {}: {e}", table_path.display())));
    println!("cargo:rustc-env=S3TIR_SPIRV_DIR={}", out_dir.display());
}

fn fail(msg: &str) -> ! {
    eprintln!("error: {msg}");
    std::process::exit(1)
}
