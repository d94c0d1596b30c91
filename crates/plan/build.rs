//! Records which code a study ran: the git commit of the checkout it was built from, and a hash
//! of any uncommitted changes, so that stages made by other code are recomputed, never reused.

use std::process::Command;

fn git(args: &[&str]) -> Option<String> {
    let out = Command::new("git").current_dir("../..").args(args).output().ok()?;
    out.status.success().then(|| String::from_utf8_lossy(&out.stdout).into_owned())
}

fn main() {
    let commit = git(&["rev-parse", "HEAD"]).map(|s| s.trim().to_owned()).unwrap_or_default();
    // Uncommitted changes to tracked files: their diff, hashed (FNV-1a), so two dirty builds of
    // different edits differ.
    let diff = git(&["diff", "HEAD", "--", "crates", "plugins", "src", "Cargo.toml", "Cargo.lock"]).unwrap_or_default();
    let dirty = if diff.is_empty() {
        String::new()
    } else {
        let h = diff.bytes().fold(0xcbf2_9ce4_8422_2325u64, |a, b| (a ^ b as u64).wrapping_mul(0x0000_0100_0000_01b3));
        format!("-dirty-{h:016x}")
    };
    println!("cargo:rustc-env=HILO_GIT_COMMIT={commit}{dirty}");
    // HEAD names a branch, whose commit lives under refs/: a commit or an amend changes that
    // file, not HEAD. (Not packed-refs: a path that does not exist reruns this script on every
    // build, and packing a branch's ref removes its file from refs/, which is a change there.)
    for p in [
        "../../.git/HEAD",
        "../../.git/index",
        "../../.git/refs",
        "../../crates",
        "../../plugins",
        "../../src",
        "../../Cargo.lock",
    ] {
        println!("cargo:rerun-if-changed={p}");
    }
}
