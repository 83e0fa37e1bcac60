//! A window of a journal as a regression test (`rigscript replay --to-test`): the replay's
//! steps written through the scenario API as `verify` writes its counterexamples
//! (`verify::testfile`), asserting in the window the outputs the rig actually produced.

use super::replay::Outcome;
use crate::verify::plan::StartPoint;
use crate::verify::testfile::{absolute, relative, RegressionTest};
use std::path::Path;

/// The test file's text for `outcome` (a replay kept its steps), whose script is `script`
/// and rig.toml `config` (if any), to be written at `out`.
pub fn render(
    outcome: &Outcome,
    out: &Path,
    script: &Path,
    config: Option<&Path>,
    window: (u64, u64),
) -> String {
    let dir = absolute(
        out.parent()
            .filter(|p| !p.as_os_str().is_empty())
            .unwrap_or(Path::new(".")),
    );
    let script = relative(&dir, &absolute(script));
    let config = config.map(|c| relative(&dir, &absolute(c)));
    let (wall, zone) = &outcome.start;
    let start = StartPoint {
        wall: wall.fixed_offset(),
        zone: if zone == "local" {
            "UTC".into()
        } else {
            zone.clone()
        },
    };
    let mut header = vec![
        format!(
            "A field run replayed: ticks {} to {} assert the outputs the rig wrote.",
            window.0, window.1
        ),
        "Written by `rigscript replay --to-test`; run it with `rigscript test`.".into(),
    ];
    if zone == "local" {
        header.push("The run's zone had no name: this test reads cron in UTC.".into());
    }
    RegressionTest {
        script: &script,
        config: config.as_deref(),
        start: &start,
        steps: &outcome.steps,
        name: &format!("field_run_ticks_{}_to_{}", window.0, window.1),
        header: &header,
    }
    .render()
}
