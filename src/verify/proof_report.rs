//! What `verify --exhaustive` tells people: the proof's line (depth and states) with what its
//! abstraction leaves out, or the shortest counterexample as a story and a written scenario
//! test; or all of it as one JSON document.

use super::exec::Target;
use super::exhaustive::{choice_text, result_line, Found, Summary, ABSTRACTED};
use super::plan::{time_text, trace};
use super::reproduce::render;
use super::testfile::absolute;
use serde_json::{json, Value};
use std::path::{Path, PathBuf};

/// The counterexample's story: its events at their times, then what failed.
pub fn story(f: &Found) -> String {
    let failed = format!(
        "{} false at {}: {}",
        f.finding.check,
        time_text(f.finding.at),
        f.finding.detail
    );
    if f.events.is_empty() {
        failed
    } else {
        format!("{} → {failed}", trace(&f.events))
    }
}

/// Where the counterexample's test goes: `DIR/<script>-<check>-exhaustive.test.rhai`.
pub fn test_path(out: &Path, script: &Path, f: &Found) -> PathBuf {
    let stem = script
        .file_stem()
        .map_or_else(|| "script".into(), |s| s.to_string_lossy().into_owned());
    out.join(format!(
        "{stem}-{}-exhaustive.test.rhai",
        f.finding.check.slug()
    ))
}

/// Writes the counterexample's scenario test under `out` (created if missing); its path.
pub fn write_test(
    out: &Path,
    target: &Target,
    s: &Summary,
    f: &Found,
    command: &str,
) -> std::io::Result<PathBuf> {
    std::fs::create_dir_all(out)?;
    let path = test_path(out, &target.script, f);
    let header = vec![
        format!(
            "Found by `{command}`: a shortest counterexample, {} choice(s) ({} event(s)), \
             after {} states.",
            f.choices.len(),
            f.events.len(),
            s.states
        ),
        story(f),
        format!("Run it: rigscript test {}", path.display()),
    ];
    let text = render(
        target,
        &absolute(out),
        &s.start,
        &f.steps,
        &f.finding,
        &header,
    );
    std::fs::write(&path, text)?;
    Ok(path)
}

/// The lines for people.
pub fn human(s: &Summary, test: Option<&Path>) -> Vec<String> {
    let mut out = vec![result_line(s)];
    match &s.found {
        Some(f) => {
            let choices: Vec<String> = f.choices.iter().map(choice_text).collect();
            out.push(format!("  choices: {}", choices.join(" · ")));
            out.push(format!("  {}", story(f)));
            if let Some(p) = test {
                out.push(format!("written to {}", p.display()));
                out.push(format!("reproduce: rigscript test {}", p.display()));
            }
        }
        None => {
            out.push(format!(
                "{} sequence(s) played, {} of them reaching a state already explored, in {:.1} s",
                s.sequences,
                s.merged,
                s.time.as_secs_f64()
            ));
            out.push(format!("vocabulary: {}", s.vocabulary.join("; ")));
            out.push("what it abstracted:".into());
            out.extend(ABSTRACTED.iter().map(|a| format!("  - {a}")));
        }
    }
    out
}

/// The JSON document.
pub fn to_json(s: &Summary, faults: bool, test: Option<&Path>, defect: Option<&str>) -> Value {
    let counterexample = s.found.as_ref().map(|f| {
        let events: Vec<Value> = f
            .events
            .iter()
            .map(|e| json!({"at_ms": e.at.as_secs_f64() * 1000.0, "event": e.action.to_string()}))
            .collect();
        let choices: Vec<String> = f.choices.iter().map(choice_text).collect();
        json!({
            "check": f.finding.check.to_string(),
            "name": f.finding.check.name(),
            "at_ms": f.finding.at.as_secs_f64() * 1000.0,
            "detail": f.finding.detail,
            "events": events,
            "choices": choices,
            "story": story(f),
            "start": s.start.wall_text(),
            "zone": s.start.zone,
            "test_file": test.map(|p| p.display().to_string()),
            "reproduced": defect.is_none() && test.is_some(),
            "defect": defect,
        })
    });
    json!({
        "mode": "exhaustive",
        "depth": s.depth,
        "complete_depth": s.complete,
        "states": s.states,
        "sequences": s.sequences,
        "merged": s.merged,
        "faults": faults,
        "search_s": s.time.as_secs_f64(),
        "start": s.start.wall_text(),
        "result": match (&counterexample, s.interrupted) {
            (Some(_), _) => "counterexample",
            (None, true) => "interrupted",
            (None, false) => "pass",
        },
        "line": result_line(s),
        "counterexample": counterexample,
        "vocabulary": s.vocabulary,
        "abstracted": ABSTRACTED,
    })
}
