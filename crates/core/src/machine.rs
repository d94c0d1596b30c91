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

/// The exit code to leave with after [`rerun_with`]: the run's own, or, where a signal ended it
/// (a crash in a native library such as the MIP solver, the kernel's out-of-memory killer), the
/// shell's 128 + signal, after a line on standard error that says so.
pub fn exit_code(status: std::process::ExitStatus) -> i32 {
    use std::os::unix::process::ExitStatusExt;
    if let Some(code) = status.code() {
        return code;
    }
    let signal = status.signal().unwrap_or(0);
    eprintln!("error: hilo was ended by signal {signal}{}", signal_words(signal));
    128 + signal
}

fn signal_words(signal: i32) -> &'static str {
    match signal {
        6 => " (SIGABRT: aborted)",
        9 => " (SIGKILL: killed, e.g. by the kernel when memory ran out)",
        11 => " (SIGSEGV: a crash, most likely in a native library such as the CBC solver)",
        _ => "",
    }
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

    /// A run ended by a signal is named, and leaves with 128 + the signal; one that exited
    /// leaves with its own code.
    #[test]
    fn a_signal_is_named_and_becomes_the_shells_code() {
        use std::os::unix::process::ExitStatusExt;
        assert_eq!(super::exit_code(std::process::ExitStatus::from_raw(11)), 139);
        assert_eq!(super::exit_code(std::process::ExitStatus::from_raw(9)), 137);
        assert_eq!(super::exit_code(std::process::ExitStatus::from_raw(3 << 8)), 3);
        assert!(super::signal_words(11).contains("SIGSEGV"));
    }

    #[cfg(target_os = "linux")]
    #[test]
    fn this_machine_reports_both() {
        assert!(super::memory_bytes().is_some_and(|b| b > 0));
        assert!(super::peak_resident_mb().is_some_and(|mb| mb > 0.0));
    }
}
