//! With the `mujoco` feature, records the folder of libmujoco.so (MUJOCO_DYNAMIC_LINK_DIR,
//! set by `.cargo/config.toml` to where scripts/install-mujoco.sh puts it) as an rpath, so
//! binaries and tests find the library without LD_LIBRARY_PATH.

fn main() {
    println!("cargo::rerun-if-env-changed=MUJOCO_DYNAMIC_LINK_DIR");
    if std::env::var_os("CARGO_FEATURE_MUJOCO").is_some()
        && let Some(dir) = std::env::var_os("MUJOCO_DYNAMIC_LINK_DIR")
    {
        println!("cargo::rustc-link-arg=-Wl,-rpath,{}", dir.to_string_lossy());
    }
}
