//! Generates the gRPC server/client code, the serde (proto3 JSON) mapping and
//! the reflection descriptor set from `proto/`. protoc comes from the
//! `protoc-bin-vendored` crate so that a fresh machine needs no system package.

use std::path::PathBuf;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    // Read at run time, not baked in when the script was compiled: a
    // build script compiled for one checkout may be run for another that
    // shares the target directory.
    let proto_root = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR")?).join("../proto");
    let proto_file = proto_root.join("humem/v1/humem.proto");
    println!("cargo:rerun-if-changed={}", proto_file.display());

    // SAFETY: build scripts are single-threaded, so nothing reads the
    // environment concurrently; `set_var` is `unsafe` only for that reason.
    #[allow(unsafe_code)]
    unsafe {
        std::env::set_var("PROTOC", protoc_bin_vendored::protoc_bin_path()?)
    };

    let out_dir = PathBuf::from(std::env::var("OUT_DIR")?);
    let descriptor_path = out_dir.join("humem_descriptor.bin");
    tonic_prost_build::configure()
        .file_descriptor_set_path(&descriptor_path)
        .compile_protos(&[&proto_file], &[&proto_root])?;

    let descriptors = std::fs::read(&descriptor_path)?;
    pbjson_build::Builder::new()
        .register_descriptors(&descriptors)?
        .build(&[".humem"])?;
    Ok(())
}
