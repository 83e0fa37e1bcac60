//! A counterexample as a ready-to-run scenario test (`*.test.rhai`): the rig started where the
//! run started, the same waits and events through the scenario API, and the check that failed
//! written so that `rigscript test` fails with its name (an invariant fails the `advance` it
//! is found false in; a built-in check is an assertion). Once the script is fixed the test
//! passes, and can stay as a regression test.

use super::checks::{Finding, Property};
use super::exec::Step;
use super::plan::{wall_step_text, Action, StartPoint};
use crate::time::duration::format_duration_exact;
use std::fmt::Write;
use std::path::{Component, Path, PathBuf};

/// Absolute, with `.` and `..` resolved where the path exists.
pub fn absolute(p: &Path) -> PathBuf {
    std::fs::canonicalize(p).unwrap_or_else(|_| {
        std::env::current_dir()
            .map(|d| d.join(p))
            .unwrap_or_else(|_| p.to_path_buf())
    })
}

/// A Rhai string literal.
fn quoted(text: &str) -> String {
    let mut out = String::from("\"");
    for c in text.chars() {
        match c {
            '"' => out.push_str("\\\""),
            '\\' => out.push_str("\\\\"),
            '\n' => out.push_str("\\n"),
            c => out.push(c),
        }
    }
    out.push('"');
    out
}

/// `path` as seen from the directory `from` (both absolute, or both relative to one place).
pub fn relative(from: &Path, path: &Path) -> PathBuf {
    let a: Vec<Component> = from.components().collect();
    let b: Vec<Component> = path.components().collect();
    let common = a.iter().zip(&b).take_while(|(x, y)| x == y).count();
    let mut out = PathBuf::new();
    for _ in common..a.len() {
        out.push("..");
    }
    for c in b.iter().skip(common) {
        out.push(c.as_os_str());
    }
    out
}

/// One action as a line of the scenario API.
fn action_line(a: &Action) -> String {
    match a {
        Action::Input { dev, ch, on } => format!("r.set_input({}, {ch}, {on});", quoted(dev)),
        Action::Inputs { dev, byte } => format!("r.set_inputs({}, {byte:#04x});", quoted(dev)),
        Action::Pulse { dev, ch, n } => format!("r.pulse({}, {ch}, {n});", quoted(dev)),
        Action::CounterTo { dev, ch, value } => format!(
            "if r.counter({d}, {ch}) < {value} {{ r.pulse({d}, {ch}, {value} - r.counter({d}, {ch})); }}",
            d = quoted(dev),
        ),
        Action::Press { dev, switch } => {
            format!("r.press({}, {});", quoted(dev), quoted(switch.name()))
        }
        Action::Release { dev, switch } => {
            format!("r.release({}, {});", quoted(dev), quoted(switch.name()))
        }
        Action::Turn {
            dev,
            rotary,
            half_turns,
        } => format!(
            "r.turn({}, {}, {half_turns});",
            quoted(dev),
            quoted(rotary.name())
        ),
        Action::Fail { dev } => format!("r.fail({});", quoted(dev)),
        Action::Restore { dev } => format!("r.restore({});", quoted(dev)),
        Action::DropAnswers { dev, n } => format!("r.drop_answers({}, {n});", quoted(dev)),
        Action::GarbleAnswers { dev, n } => format!("r.garble_answers({}, {n});", quoted(dev)),
        Action::LateAnswers { dev, n, by } => format!(
            "r.late_answers({}, {n}, {});",
            quoted(dev),
            quoted(&format_duration_exact(*by))
        ),
        Action::DuplicateAnswers { dev, n } => {
            format!("r.duplicate_answers({}, {n});", quoted(dev))
        }
        Action::PowerCycle { dev } => format!("r.power_cycle({});", quoted(dev)),
        Action::Stall { by } => format!("r.stall({});", quoted(&format_duration_exact(*by))),
        Action::WallStep { seconds } => {
            format!("r.step_wall({});", quoted(&wall_step_text(*seconds)))
        }
        Action::Stop => "r.signal_stop();".into(),
    }
}

/// A step as a line of the scenario API.
fn step_line(step: &Step) -> String {
    match step {
        Step::Advance(d) => format!("r.advance({});", quoted(&format_duration_exact(*d))),
        Step::Act(a) => action_line(a),
        Step::End => "r.end();".into(),
    }
}

/// A written test's opening: the `header` as comments, `fn test_NAME() {` and the rig started
/// as the run was (`script`, and `config` when it had one, at `start`).
fn opening(
    header: &[String],
    name: &str,
    script: &Path,
    start: &StartPoint,
    config: Option<&Path>,
) -> String {
    let mut out = String::new();
    for line in header {
        let _ = writeln!(out, "// {line}");
    }
    let _ = writeln!(out);
    let _ = writeln!(out, "fn test_{name}() {{");
    let script = quoted(&script.to_string_lossy());
    let wall = quoted(&start.wall_text());
    let zone = quoted(&start.zone);
    match config {
        Some(c) => {
            let c = quoted(&c.to_string_lossy());
            let _ = writeln!(out, "    let r = rig_at({script}, {wall}, {zone}, {c});");
        }
        None => {
            let _ = writeln!(out, "    let r = rig_at({script}, {wall}, {zone});");
        }
    }
    out
}

/// What the test file needs to know.
#[derive(Debug, Clone)]
pub struct TestFile<'a> {
    /// The script, relative to the test file's directory.
    pub script: &'a Path,
    /// The rig.toml, relative to the test file's directory, if one was given.
    pub config: Option<&'a Path>,
    /// Where the run started.
    pub start: &'a StartPoint,
    /// What it did.
    pub steps: &'a [Step],
    /// What failed.
    pub finding: &'a Finding,
    /// (device, `"outputs"` or `"relay"`, safe value) for the built-in safety checks.
    pub safe_states: &'a [(String, &'static str, u8)],
    /// Comment lines at the top.
    pub header: &'a [String],
}

impl TestFile<'_> {
    /// The file's text.
    pub fn render(&self) -> String {
        let mut out = opening(
            self.header,
            &self.finding.check.slug(),
            self.script,
            self.start,
            self.config,
        );
        let last_advance = self
            .steps
            .iter()
            .rposition(|s| matches!(s, Step::Advance(_)));
        for (i, step) in self.steps.iter().enumerate() {
            let line = match step {
                Step::Advance(_) if Some(i) == last_advance => {
                    let mut l = step_line(step);
                    if let Property::Invariant(_) = self.finding.check {
                        let _ = write!(l, " // {} is found false here", self.finding.check);
                    }
                    l
                }
                _ => step_line(step),
            };
            let _ = writeln!(out, "    {line}");
        }
        for line in self.assertions() {
            let _ = writeln!(out, "    {line}");
        }
        let _ = writeln!(out, "}}");
        out
    }

    fn assertions(&self) -> Vec<String> {
        let what = quoted(&format!("{}", self.finding.check));
        match &self.finding.check {
            Property::Invariant(_) => Vec::new(),
            Property::ScriptError | Property::OverBudget => {
                vec![format!("assert_eq(r.errors(), [], {what});")]
            }
            Property::HeldSafe | Property::EndSafe => self
                .safe_states
                .iter()
                .filter(|(dev, ..)| self.finding.devices.contains(dev))
                .map(|(dev, kind, v)| {
                    let value = if *kind == "outputs" {
                        format!("{v:#04x}")
                    } else {
                        v.to_string()
                    };
                    format!(
                        "assert_eq(r.{kind}({d}), {value}, {m});",
                        d = quoted(dev),
                        m = quoted(&format!("{}: {dev}", self.finding.check)),
                    )
                })
                .collect(),
        }
    }
}

/// A step of a regression test and the outputs it asserts after it: (device, `"outputs"`
/// or `"relay"`, value).
pub type AssertedStep = (Step, Vec<(String, &'static str, u8)>);

/// A field run as a regression test (`rigscript replay --to-test`): the rig started where the
/// run started, the field's events through the scenario API, and after a wait the outputs
/// the rig had written by then asserted, so the test passes while the script writes what it
/// wrote in the field and fails where it writes otherwise.
#[derive(Debug, Clone)]
pub struct RegressionTest<'a> {
    /// The script, relative to the test file's directory.
    pub script: &'a Path,
    /// The rig.toml, relative to the test file's directory, if the run had one.
    pub config: Option<&'a Path>,
    /// Where the run started.
    pub start: &'a StartPoint,
    /// The steps, each with the outputs to assert after it.
    pub steps: &'a [AssertedStep],
    /// The test's name (a slug).
    pub name: &'a str,
    /// Comment lines at the top.
    pub header: &'a [String],
}

impl RegressionTest<'_> {
    /// The file's text.
    pub fn render(&self) -> String {
        let mut out = opening(self.header, self.name, self.script, self.start, self.config);
        for (step, asserts) in self.steps {
            let _ = writeln!(out, "    {}", step_line(step));
            for (dev, kind, value) in asserts {
                let _ = writeln!(
                    out,
                    "    assert_eq(r.{kind}({d}), {value}, {m});",
                    d = quoted(dev),
                    m = quoted(&format!("{dev} as the run wrote it")),
                );
            }
        }
        let _ = writeln!(out, "}}");
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol::trc1000::Switch;
    use std::sync::Arc;
    use std::time::Duration;

    #[test]
    fn paths_are_written_from_the_test_files_directory() {
        assert_eq!(
            relative(
                Path::new("/w/verify-failures"),
                Path::new("/w/scripts/i.rhai")
            ),
            PathBuf::from("../scripts/i.rhai")
        );
        assert_eq!(
            relative(Path::new("/w"), Path::new("/w/i.rhai")),
            PathBuf::from("i.rhai")
        );
    }

    #[test]
    fn a_counterexample_reads_as_a_scenario_test() {
        let start = StartPoint {
            wall: chrono::DateTime::parse_from_rfc3339("2026-03-28T12:00:00.250Z").unwrap(),
            zone: "UTC".into(),
        };
        let io: Arc<str> = Arc::from("io");
        let steps = vec![
            Step::Advance(Duration::from_millis(10)),
            Step::Act(Action::Inputs {
                dev: io.clone(),
                byte: 0x0f,
            }),
            Step::Act(Action::Press {
                dev: Arc::from("panel"),
                switch: Switch::new(12).unwrap(),
            }),
            Step::Advance(Duration::from_millis(30)),
        ];
        let finding = Finding {
            check: Property::Invariant("power only with guards closed".into()),
            at: Duration::from_millis(40),
            detail: String::new(),
            devices: Vec::new(),
        };
        let text = TestFile {
            script: Path::new("../scripts/interlock.rhai"),
            config: None,
            start: &start,
            steps: &steps,
            finding: &finding,
            safe_states: &[],
            header: &["found by verify".into()],
        }
        .render();
        assert_eq!(
            text,
            "// found by verify\n\nfn test_power_only_with_guards_closed() {\n    let r = \
             rig_at(\"../scripts/interlock.rhai\", \"2026-03-28T12:00:00.250Z\", \"UTC\");\n    \
             r.advance(\"10ms\");\n    r.set_inputs(\"io\", 0x0f);\n    r.press(\"panel\", \
             \"S12\");\n    r.advance(\"30ms\"); // invariant \"power only with guards closed\" \
             is found false here\n}\n"
        );
    }
}
