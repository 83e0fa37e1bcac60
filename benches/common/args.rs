//! A benchmark's command line: `cargo bench` passes `--bench` (a full run; without it, as under
//! `cargo test --all-targets`, a short smoke pass), and words after `--` pick what to run.

/// What the command line asks for.
pub struct BenchArgs {
    /// `--bench` was given: measure in full.
    pub full: bool,
    /// The words that pick rows or cases (`cargo bench --bench NAME -- 9600 libmodbus`).
    pub words: Vec<String>,
}

impl BenchArgs {
    /// The process's own arguments.
    pub fn from_env() -> Self {
        let args: Vec<String> = std::env::args().skip(1).collect();
        Self {
            full: args.iter().any(|a| a == "--bench"),
            words: args.into_iter().filter(|a| !a.starts_with("--")).collect(),
        }
    }

    /// Whether the case called `name` runs: no words given, or one of them is part of `name`.
    #[allow(dead_code)] // not every benchmark picks cases by a single name
    pub fn picks(&self, name: &str) -> bool {
        self.words.is_empty() || self.words.iter().any(|w| name.contains(w.as_str()))
    }
}
