//! JUnit XML, as Jenkins (junit plugin) and GitLab (`artifacts:reports:junit`) read it:
//! `<testsuites>` of `<testsuite>`s of `<testcase>`s, a failed case carrying `<failure>` (a
//! check that did not hold) or `<error>` (something that kept it from being checked).
//!
//! Written by hand: the format is small, and what matters is escaping. Text and attribute
//! values are escaped for XML, and characters XML 1.0 cannot carry at all (control characters
//! other than tab, newline and carriage return) are written as `\u{..}` so nothing a script
//! names can make the report unreadable.
//!
//! Not quick-junit: it drops tabs, carriage returns and control characters and writes line
//! breaks raw inside attributes (which XML readers turn into spaces), so a case named with them
//! does not read back as written; and it would bring six crates for some sixty lines.

use std::fmt::Write as _;
use std::io;
use std::path::Path;
use std::time::Duration;

/// What became of one test case.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Outcome {
    /// It passed.
    Passed,
    /// A check did not hold (`<failure>`).
    Failure {
        /// One line saying what failed.
        message: String,
        /// The kind of failure, such as `measurement`.
        kind: String,
        /// Longer text, if any.
        detail: String,
    },
    /// Something kept it from being checked (`<error>`).
    Error {
        /// One line saying what went wrong.
        message: String,
        /// The kind of error, such as `exit status 3`.
        kind: String,
        /// Longer text, if any.
        detail: String,
    },
}

/// One `<testcase>`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TestCase {
    /// Its name (shown by CI, and the key of its history: keep it stable between runs).
    pub name: String,
    /// Its group, such as the script or test file.
    pub classname: String,
    /// How long it took.
    pub time: Duration,
    /// Pass, failure or error.
    pub outcome: Outcome,
    /// Name-value pairs (`<properties>`), such as a measurement's value and limits.
    pub properties: Vec<(String, String)>,
    /// Text for `<system-out>` (GitLab shows it beside the case), if any.
    pub output: String,
}

impl TestCase {
    /// A passed case with no properties or output.
    pub fn passed(name: impl Into<String>, classname: impl Into<String>) -> Self {
        Self {
            name: name.into(),
            classname: classname.into(),
            time: Duration::ZERO,
            outcome: Outcome::Passed,
            properties: Vec::new(),
            output: String::new(),
        }
    }
}

/// One `<testsuite>`.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TestSuite {
    /// Its name.
    pub name: String,
    /// When it started, as `YYYY-MM-DDTHH:MM:SS` (the form the JUnit schema allows).
    pub timestamp: String,
    /// How long it took.
    pub time: Duration,
    /// Name-value pairs for the whole suite.
    pub properties: Vec<(String, String)>,
    /// Its cases, in order.
    pub cases: Vec<TestCase>,
    /// Text for the suite's `<system-err>` (such as a note that cases were left out), if any.
    pub notes: String,
}

impl TestSuite {
    /// Cases that failed a check.
    pub fn failures(&self) -> usize {
        self.count(|o| matches!(o, Outcome::Failure { .. }))
    }

    /// Cases that could not be checked.
    pub fn errors(&self) -> usize {
        self.count(|o| matches!(o, Outcome::Error { .. }))
    }

    fn count(&self, which: impl Fn(&Outcome) -> bool) -> usize {
        self.cases.iter().filter(|c| which(&c.outcome)).count()
    }
}

/// The whole document for `suites`.
pub fn render(suites: &[TestSuite]) -> String {
    let mut out = String::from("<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n");
    let tests: usize = suites.iter().map(|s| s.cases.len()).sum();
    let failures: usize = suites.iter().map(TestSuite::failures).sum();
    let errors: usize = suites.iter().map(TestSuite::errors).sum();
    let time: Duration = suites.iter().map(|s| s.time).sum();
    let _ = writeln!(
        out,
        "<testsuites name=\"rigscript\" tests=\"{tests}\" failures=\"{failures}\" \
         errors=\"{errors}\" time=\"{}\">",
        seconds(time)
    );
    for (id, suite) in suites.iter().enumerate() {
        render_suite(&mut out, id, suite);
    }
    out.push_str("</testsuites>\n");
    out
}

fn render_suite(out: &mut String, id: usize, s: &TestSuite) {
    let _ = writeln!(
        out,
        "  <testsuite id=\"{id}\" name=\"{}\" tests=\"{}\" failures=\"{}\" errors=\"{}\" \
         skipped=\"0\" time=\"{}\" timestamp=\"{}\" hostname=\"{}\">",
        attr(&s.name),
        s.cases.len(),
        s.failures(),
        s.errors(),
        seconds(s.time),
        attr(&s.timestamp),
        attr(&hostname()),
    );
    render_properties(out, "    ", &s.properties);
    for case in &s.cases {
        render_case(out, case);
    }
    if !s.notes.is_empty() {
        let _ = writeln!(out, "    <system-err>{}</system-err>", text(&s.notes));
    }
    out.push_str("  </testsuite>\n");
}

fn render_case(out: &mut String, c: &TestCase) {
    let _ = write!(
        out,
        "    <testcase name=\"{}\" classname=\"{}\" time=\"{}\"",
        attr(&c.name),
        attr(&c.classname),
        seconds(c.time)
    );
    if c.outcome == Outcome::Passed && c.properties.is_empty() && c.output.is_empty() {
        out.push_str("/>\n");
        return;
    }
    out.push_str(">\n");
    render_properties(out, "      ", &c.properties);
    match &c.outcome {
        Outcome::Passed => {}
        Outcome::Failure {
            message,
            kind,
            detail,
        } => render_problem(out, "failure", message, kind, detail),
        Outcome::Error {
            message,
            kind,
            detail,
        } => render_problem(out, "error", message, kind, detail),
    }
    if !c.output.is_empty() {
        let _ = writeln!(out, "      <system-out>{}</system-out>", text(&c.output));
    }
    out.push_str("    </testcase>\n");
}

fn render_problem(out: &mut String, tag: &str, message: &str, kind: &str, detail: &str) {
    let _ = writeln!(
        out,
        "      <{tag} message=\"{}\" type=\"{}\">{}</{tag}>",
        attr(message),
        attr(kind),
        text(if detail.is_empty() { message } else { detail })
    );
}

fn render_properties(out: &mut String, indent: &str, properties: &[(String, String)]) {
    if properties.is_empty() {
        return;
    }
    let _ = writeln!(out, "{indent}<properties>");
    for (name, value) in properties {
        let _ = writeln!(
            out,
            "{indent}  <property name=\"{}\" value=\"{}\"/>",
            attr(name),
            attr(value)
        );
    }
    let _ = writeln!(out, "{indent}</properties>");
}

/// A suite timestamp as the JUnit schema writes it (`YYYY-MM-DDTHH:MM:SS`, no zone).
pub fn timestamp<Tz: chrono::TimeZone>(at: &chrono::DateTime<Tz>) -> String
where
    Tz::Offset: std::fmt::Display,
{
    at.format("%Y-%m-%dT%H:%M:%S").to_string()
}

/// The local time now as a suite timestamp.
pub fn timestamp_now() -> String {
    timestamp(&chrono::Local::now())
}

/// Seconds with millisecond precision, as JUnit readers expect.
fn seconds(d: Duration) -> String {
    format!("{:.3}", d.as_secs_f64())
}

fn hostname() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .map(|h| h.trim().to_string())
        .unwrap_or_default()
}

/// `text` escaped for element content.
pub fn text(text: &str) -> String {
    escape(text, false)
}

/// `text` escaped for a double-quoted attribute value (line breaks kept as character
/// references, which attribute normalization would otherwise turn into spaces).
pub fn attr(text: &str) -> String {
    escape(text, true)
}

fn escape(text: &str, attribute: bool) -> String {
    let mut out = String::with_capacity(text.len());
    for c in text.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' if attribute => out.push_str("&quot;"),
            '\'' if attribute => out.push_str("&apos;"),
            '\n' if attribute => out.push_str("&#10;"),
            '\r' => out.push_str("&#13;"),
            '\t' if attribute => out.push_str("&#9;"),
            '\t' | '\n' => out.push(c),
            c if allowed_in_xml(c) => out.push(c),
            c => {
                let _ = write!(out, "\\u{{{:x}}}", u32::from(c));
            }
        }
    }
    out
}

/// Whether XML 1.0 can carry `c` at all (its `Char` production, minus the line breaks and tab
/// handled above).
fn allowed_in_xml(c: char) -> bool {
    matches!(u32::from(c), 0x20..=0xD7FF | 0xE000..=0xFFFD | 0x10000..=0x10FFFF)
}

/// Writes the document for `suites` to `path` whole: into a file beside it, then renamed over
/// it, so a CI job never reads half a report.
pub fn write(path: &Path, suites: &[TestSuite]) -> io::Result<()> {
    let name = path.file_name().ok_or_else(|| {
        io::Error::new(io::ErrorKind::InvalidInput, "the report path names no file")
    })?;
    let mut partial = name.to_os_string();
    partial.push(format!(".{}.partial", std::process::id()));
    let partial = path.with_file_name(partial);
    std::fs::write(&partial, render(suites))
        .and_then(|()| std::fs::rename(&partial, path))
        .inspect_err(|_| {
            let _ = std::fs::remove_file(&partial);
        })
}

/// Refuses a report path that cannot be written (a directory, or a file in a missing
/// directory), so a command can say so before it runs anything.
pub fn check_path(path: &Path) -> Result<(), String> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    if path.is_dir() {
        return Err(format!(
            "--junit {}: that is a directory; give a file name such as report.xml",
            path.display()
        ));
    }
    if !dir.is_dir() {
        return Err(format!(
            "--junit {}: the directory {} does not exist; create it or give another path",
            path.display(),
            dir.display()
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn suite(cases: Vec<TestCase>) -> TestSuite {
        TestSuite {
            name: "s".into(),
            timestamp: "2026-03-28T12:00:00".into(),
            time: Duration::from_millis(1500),
            properties: vec![("script".into(), "a.rhai".into())],
            cases,
            notes: String::new(),
        }
    }

    #[test]
    fn escaping_covers_markup_quotes_line_breaks_and_unusable_characters() {
        assert_eq!(text("a<b>&c \"q\" 'x'"), "a&lt;b&gt;&amp;c \"q\" 'x'");
        assert_eq!(attr("a\"b'c\nd\te"), "a&quot;b&apos;c&#10;d&#9;e");
        assert_eq!(text("line\nnext\r"), "line\nnext&#13;");
        assert_eq!(text("bell\u{7}nul\u{0}"), "bell\\u{7}nul\\u{0}");
        assert_eq!(text("\u{FFFE}ok µ ✓"), "\\u{fffe}ok µ ✓");
    }

    #[test]
    fn counts_and_shapes_follow_the_outcomes() {
        let mut failed = TestCase::passed("v", "a.rhai");
        failed.outcome = Outcome::Failure {
            message: "v = 5, above 3".into(),
            kind: "measurement".into(),
            detail: String::new(),
        };
        let mut error = TestCase::passed("run", "a.rhai");
        error.outcome = Outcome::Error {
            message: "exit status 3".into(),
            kind: "exit status 3".into(),
            detail: "device io did not answer".into(),
        };
        let doc = render(&[suite(vec![TestCase::passed("ok", "a.rhai"), failed, error])]);
        assert!(doc.starts_with("<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n<testsuites"));
        assert!(doc.contains("tests=\"3\" failures=\"1\" errors=\"1\" time=\"1.500\">"));
        assert!(doc.contains("<testcase name=\"ok\" classname=\"a.rhai\" time=\"0.000\"/>"));
        assert!(doc.contains(
            "<failure message=\"v = 5, above 3\" type=\"measurement\">v = 5, above 3</failure>"
        ));
        assert!(doc.contains(
            "<error message=\"exit status 3\" type=\"exit status 3\">device io did not \
             answer</error>"
        ));
        assert!(doc.contains("<property name=\"script\" value=\"a.rhai\"/>"));
    }

    #[test]
    fn whatever_a_script_names_parses_back_as_written() {
        let nasty = "volts <\"DO&1\"> 'x'\n\tnext\r µ✓";
        let mut case = TestCase::passed(nasty, nasty);
        case.outcome = Outcome::Failure {
            message: nasty.into(),
            kind: "measurement".into(),
            detail: format!("{nasty}]]> </failure>"),
        };
        case.properties = vec![(nasty.into(), nasty.into())];
        case.output = "bell \u{7} here".into();
        let doc = render(&[suite(vec![case])]);
        let parsed = roxmltree::Document::parse(&doc).unwrap_or_else(|e| panic!("{e}:\n{doc}"));
        let tc = parsed
            .descendants()
            .find(|n| n.has_tag_name("testcase"))
            .unwrap();
        assert_eq!(tc.attribute("name"), Some(nasty));
        assert_eq!(tc.attribute("classname"), Some(nasty));
        let failure = tc.children().find(|n| n.has_tag_name("failure")).unwrap();
        assert_eq!(failure.attribute("message"), Some(nasty));
        assert_eq!(
            failure.text(),
            Some(format!("{nasty}]]> </failure>").as_str())
        );
        let property = tc
            .descendants()
            .find(|n| n.has_tag_name("property"))
            .unwrap();
        assert_eq!(property.attribute("value"), Some(nasty));
        let out = tc
            .children()
            .find(|n| n.has_tag_name("system-out"))
            .unwrap();
        assert_eq!(out.text(), Some("bell \\u{7} here"));
    }

    #[test]
    fn a_report_replaces_the_old_one_whole() {
        let dir =
            std::env::temp_dir().join(format!("rigscript-junit-write-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("report.xml");
        std::fs::write(&path, "old").unwrap();
        write(&path, &[suite(Vec::new())]).unwrap();
        let doc = std::fs::read_to_string(&path).unwrap();
        assert!(doc.contains("tests=\"0\""), "{doc}");
        let left: Vec<_> = std::fs::read_dir(&dir).unwrap().collect();
        assert_eq!(left.len(), 1, "no partial file left behind");
        let e = write(&dir.join("missing/r.xml"), &[]).unwrap_err();
        assert_eq!(e.kind(), io::ErrorKind::NotFound);
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
