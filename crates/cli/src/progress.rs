//! Progress on the terminal: bars when stderr is a terminal; otherwise (logs, CI, cluster jobs)
//! a plain line every ten seconds with the step, rate and time left.

use hilo_study::Progress;
use indicatif::{ProgressBar, ProgressStyle};
use std::io::IsTerminal;
use std::time::{Duration, Instant};

/// How often a plain progress line is printed when stderr is not a terminal.
const EVERY: Duration = Duration::from_secs(10);

#[derive(Debug)]
pub struct Reporter {
    tty: bool,
    bar: Option<ProgressBar>,
    label: String,
    started: Instant,
    last: Instant,
}

impl Default for Reporter {
    fn default() -> Self {
        Reporter::new()
    }
}

/// A duration for people: `45 s`, `3 min 20 s`, `1 h 05 min`.
pub fn human_duration(s: f64) -> String {
    if !s.is_finite() {
        return "?".into();
    }
    let s = s.max(0.0).round() as u64;
    match s {
        0..=59 => format!("{s} s"),
        60..=3599 => format!("{} min {:02} s", s / 60, s % 60),
        _ => format!("{} h {:02} min", s / 3600, (s % 3600) / 60),
    }
}

impl Reporter {
    pub fn new() -> Self {
        let now = Instant::now();
        Reporter { tty: std::io::stderr().is_terminal(), bar: None, label: String::new(), started: now, last: now }
    }

    /// A line for people, above any bar.
    pub fn line(&self, msg: &str) {
        match &self.bar {
            Some(b) => b.println(msg),
            None => eprintln!("{msg}"),
        }
    }

    /// A task moved: `done` of `total` `unit`s (e.g. "frames", "steps"), with a message.
    pub fn task(&mut self, label: &str, done: usize, total: usize, unit: &str) {
        if label != self.label {
            self.finish();
            self.label = label.to_owned();
            self.started = Instant::now();
            self.last = self.started;
            if self.tty {
                let bar = ProgressBar::new(total as u64);
                bar.set_style(
                    ProgressStyle::with_template(&format!(
                        "{{msg}} [{{bar:30}}] {{pos}}/{{len}} {unit}, {{per_sec}}, ETA {{eta}}"
                    ))
                    .unwrap_or_else(|_| ProgressStyle::default_bar())
                    .progress_chars("=> "),
                );
                bar.set_message(label.to_owned());
                self.bar = Some(bar);
            }
        }
        match &self.bar {
            Some(b) => {
                b.set_length(total as u64);
                b.set_position(done as u64);
            }
            None => {
                if self.last.elapsed() >= EVERY || (done == total && total > 0) {
                    self.last = Instant::now();
                    let secs = self.started.elapsed().as_secs_f64();
                    let rate = done as f64 / secs.max(1e-9);
                    let left = if rate > 0.0 { (total.saturating_sub(done)) as f64 / rate } else { f64::NAN };
                    eprintln!(
                        "{label}: {done}/{total} {unit} ({rate:.1} {unit}/s, {} elapsed, {} left)",
                        human_duration(secs),
                        human_duration(left)
                    );
                }
            }
        }
    }

    /// The message shown beside a bar (on a terminal only).
    pub fn message(&self, msg: String) {
        if let Some(b) = &self.bar {
            b.set_message(msg);
        }
    }

    /// The current task is over.
    pub fn finish(&mut self) {
        if let Some(b) = self.bar.take() {
            b.finish_and_clear();
        }
        self.label.clear();
    }

    /// Handles a study's progress events.
    pub fn study(&mut self, p: Progress) {
        match p {
            Progress::Stage(s) => self.line(&format!("[study] {s}")),
            Progress::Task { label, done, total, unit } => self.task(label, done, total, unit),
            Progress::TaskDone => self.finish(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn durations_read_like_a_person_writes_them() {
        assert_eq!(human_duration(45.2), "45 s");
        assert_eq!(human_duration(200.0), "3 min 20 s");
        assert_eq!(human_duration(3900.0), "1 h 05 min");
        assert_eq!(human_duration(f64::NAN), "?");
    }
}
