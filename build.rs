//! Compiles the virtual-time shim (`shim/`, a dependency-free cdylib) with the same rustc and
//! target as climbsim, so that `src/virtual_time/shim_file.rs` can embed it: `cargo build`,
//! `cargo test` and `cargo install` all give a climbsim that carries its own shim, and no stale
//! `.so` can sit beside a newer binary (docs/virtual-time.md, "How climbsim finds the shim").

use std::path::PathBuf;
use std::process::Command;

fn main() {
    println!("cargo:rerun-if-changed=shim/src");
    println!("cargo:rerun-if-changed=build.rs");
    let out = PathBuf::from(std::env::var_os("OUT_DIR").expect("cargo sets OUT_DIR"));
    let rustc = std::env::var_os("RUSTC").unwrap_or_else(|| "rustc".into());
    let target = std::env::var("TARGET").expect("cargo sets TARGET");
    let shim = out.join("libclimbsim_shim.so");
    let status = Command::new(&rustc)
        .args(["--crate-type", "cdylib", "--edition", "2024", "--crate-name", "climbsim_shim", "--target", &target])
        .args(["-C", "opt-level=2", "-C", "panic=abort", "-C", "debuginfo=0", "-C", "strip=symbols"])
        .arg("shim/src/lib.rs")
        .arg("-o")
        .arg(&shim)
        .status();
    match status {
        Ok(status) if status.success() => {}
        Ok(status) => panic!("compiling the virtual-time shim (shim/src/lib.rs) failed: {status}"),
        Err(error) => panic!("cannot run {} to compile the virtual-time shim: {error}", rustc.to_string_lossy()),
    }
}
