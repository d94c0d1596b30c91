//! What the machine and this process hold, as Linux reports it in `/proc`: `None` where the
//! system does not say.

/// The machine's memory (`MemTotal` in /proc/meminfo), bytes.
pub fn memory_bytes() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    Some(kib_field(&text, "MemTotal:")? * 1024)
}

/// This process's peak resident memory (`VmHWM` in /proc/self/status), MB.
pub fn peak_resident_mb() -> Option<f64> {
    let text = std::fs::read_to_string("/proc/self/status").ok()?;
    Some(kib_field(&text, "VmHWM:")? as f64 / 1024.0)
}

/// Runs this program again with the same arguments and the variables of `env` that are unset
/// here, and returns its status; `None` (nothing run) when every one is set already. For what a
/// library reads from the environment once, at its start, which a running process cannot set
/// for itself without `unsafe`.
pub fn rerun_with(env: &[(&str, &str)]) -> std::io::Result<Option<std::process::ExitStatus>> {
    let unset: Vec<(&str, &str)> = env.iter().copied().filter(|(k, _)| std::env::var_os(k).is_none()).collect();
    if unset.is_empty() {
        return Ok(None);
    }
    let exe = std::env::current_exe()?;
    std::process::Command::new(exe).args(std::env::args_os().skip(1)).envs(unset).status().map(Some)
}

/// The value of a `Name:   1234 kB` line.
fn kib_field(text: &str, name: &str) -> Option<u64> {
    text.lines().find_map(|l| l.strip_prefix(name))?.trim().trim_end_matches("kB").trim().parse().ok()
}

#[cfg(test)]
mod tests {
    #[test]
    fn reads_kib_fields() {
        let text = "MemTotal:       24588888 kB\nVmHWM:\t  2048 kB\n";
        assert_eq!(super::kib_field(text, "MemTotal:"), Some(24_588_888));
        assert_eq!(super::kib_field(text, "VmHWM:"), Some(2048));
        assert_eq!(super::kib_field(text, "VmRSS:"), None);
        assert_eq!(super::kib_field("VmHWM: lots kB", "VmHWM:"), None);
    }

    #[cfg(target_os = "linux")]
    #[test]
    fn this_machine_reports_both() {
        assert!(super::memory_bytes().is_some_and(|b| b > 0));
        assert!(super::peak_resident_mb().is_some_and(|mb| mb > 0.0));
    }
}
