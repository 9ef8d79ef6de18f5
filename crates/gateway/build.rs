//! The build date for OPC UA's `ServerStatus/BuildInfo`: `SOURCE_DATE_EPOCH` when set (reproducible
//! builds), else now; rerun when the gateway's sources change, so it is the date of this code's build.

fn main() {
    println!("cargo:rerun-if-env-changed=SOURCE_DATE_EPOCH");
    println!("cargo:rerun-if-changed=src");
    println!("cargo:rerun-if-changed=Cargo.toml");
    let unix_s = std::env::var("SOURCE_DATE_EPOCH")
        .ok()
        .and_then(|s| s.trim().parse::<u64>().ok())
        .unwrap_or_else(|| {
            std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0, |d| d.as_secs())
        });
    println!("cargo:rustc-env=RETROCOMP_BUILD_UNIX_S={unix_s}");
}
