//! `rigscript replay FILE [SCRIPT]`: replays a run's journal (`run --journal`) in virtual time
//! against the recorded script or an edited one, and says whether the outputs came out as the
//! run wrote them, or the first tick where they did not with the inputs around it; with
//! `--to-test OUT` writes the window as a regression test. Exit status 0 when the outputs
//! are the run's, 1 when they differ, 2 when the journal or the script cannot be read.

use crate::journal::replay::{replay, Divergence, Options, Outcome};
use crate::journal::{read_journal, to_test, Entry, What};
use crate::runtime::exit;
use crate::text_file::{read_text, TextKind};
use clap::Args;
use serde_json::json;
use std::path::{Path, PathBuf};

/// Options of `rigscript replay`.
#[derive(Debug, Args)]
pub struct ReplayArgs {
    /// The journal (`run --journal FILE`); a part that rotation started is read after the
    /// part before it (FILE.1).
    pub journal: PathBuf,
    /// A script to replay instead of the recorded one (an edited version of it).
    pub script: Option<PathBuf>,
    /// Replay up to this tick only.
    #[arg(long, value_name = "TICK")]
    pub until: Option<u64>,
    /// With --to-test: assert the outputs from this tick on (the events before it are
    /// played too: the script's state depends on them).
    #[arg(long, value_name = "TICK", requires = "to_test")]
    pub from: Option<u64>,
    /// Print the result as one JSON object.
    #[arg(long)]
    pub json: bool,
    /// Write the window as a scenario test (*.test.rhai) asserting the outputs the rig wrote.
    #[arg(long, value_name = "OUT")]
    pub to_test: Option<PathBuf>,
}

fn what_text(e: &Entry) -> String {
    let w = match &e.what {
        What::Inputs { dev, byte } => format!("{dev} inputs {byte:#04x}"),
        What::Counters { dev, values } => format!("{dev} counters {values:?}"),
        What::Switches { dev, pressed } => {
            let names: Vec<&str> = pressed.iter().map(|s| s.name()).collect();
            format!("{dev} switches pressed [{}]", names.join(", "))
        }
        What::Rotaries { dev, values } => format!("{dev} rotaries {values:?}"),
        What::Outputs { dev, value, cause } => format!("{dev} wrote {value:#04x} ({cause})"),
        What::Lost { dev, cause } => format!("{dev} lost: {cause}"),
        What::Back { dev } => format!("{dev} back"),
        What::Ended { status, reason } => format!("ended with {status}: {reason}"),
        other => format!("{other:?}"),
    };
    format!("tick {}: {w}", e.tick)
}

fn divergence_text(d: &Divergence) -> String {
    let mut out = format!("first divergence at tick {}:\n", d.tick);
    let side = |e: &Option<Entry>| e.as_ref().map_or("nothing more".into(), what_text);
    out.push_str(&format!("  the run:    {}\n", side(&d.recorded)));
    out.push_str(&format!("  the replay: {}\n", side(&d.replayed)));
    if !d.around.is_empty() {
        out.push_str("the field around it:\n");
        for e in &d.around {
            out.push_str(&format!("  {}\n", what_text(e)));
        }
    }
    out
}

fn json_of(o: &Outcome, journal: &Path) -> serde_json::Value {
    json!({
        "journal": journal.display().to_string(),
        "same_script": o.same_script,
        "ticks": o.ticks,
        "outputs": o.recorded.len(),
        "outputs_replayed": o.replayed.len(),
        "exact": o.divergence.is_none(),
        "divergence": o.divergence.as_ref().map(|d| json!({
            "tick": d.tick,
            "recorded": d.recorded.as_ref().map(Entry::line),
            "replayed": d.replayed.as_ref().map(Entry::line),
            "around": d.around.iter().map(Entry::line).collect::<Vec<_>>(),
        })),
        "unrecorded": o.unrecorded.iter().map(|u| json!({
            "device": u.dev, "read": u.item, "assumed": u.assumed,
        })).collect::<Vec<_>>(),
        "notes": o.notes,
    })
}

/// Runs `rigscript replay`; returns the exit status.
pub fn run(args: ReplayArgs) -> i32 {
    let fail = |e: &dyn std::fmt::Display| {
        eprintln!("rigscript replay: {e}");
        exit::USAGE
    };
    let journal = match read_journal(&args.journal) {
        Ok(j) => j,
        Err(e) => return fail(&e),
    };
    let script = match &args.script {
        Some(p) => match read_text(p, TextKind::Script) {
            Ok(text) => Some((text, p.display().to_string())),
            Err(e) => return fail(&format!("cannot read {}: {e}", p.display())),
        },
        None => None,
    };
    let options = Options {
        script,
        until: args.until,
        steps_from: args.to_test.as_ref().map(|_| args.from.unwrap_or(0)),
    };
    let outcome = match replay(&journal, &options) {
        Ok(o) => o,
        Err(e) => return fail(&e),
    };
    if let Some(out) = &args.to_test {
        let script = args
            .script
            .clone()
            .unwrap_or_else(|| PathBuf::from(&journal.header.script_file));
        let config = journal.header.config_file.as_ref().map(PathBuf::from);
        let window = (args.from.unwrap_or(0), outcome.ticks);
        let text = to_test::render(&outcome, out, &script, config.as_deref(), window);
        if let Err(e) = std::fs::write(out, text) {
            return fail(&format!("cannot write {}: {e}", out.display()));
        }
    }
    if args.json {
        println!("{}", json_of(&outcome, &args.journal));
    } else {
        let which = if outcome.same_script {
            "the recorded script"
        } else {
            "an edited script"
        };
        println!(
            "replayed {} ticks of {} against {which} ({} outputs written in the run)",
            outcome.ticks,
            args.journal.display(),
            outcome.recorded.len()
        );
        match &outcome.divergence {
            None => println!("outputs: as the run wrote them"),
            Some(d) => print!("{}", divergence_text(d)),
        }
        if !outcome.unrecorded.is_empty() {
            println!("read but not recorded (the run never read them; the replay assumed):");
            for u in &outcome.unrecorded {
                println!("  {} {}: {}", u.dev, u.item, u.assumed);
            }
        }
        for n in &outcome.notes {
            println!("note: {n}");
        }
        if let Some(out) = &args.to_test {
            println!("wrote {}", out.display());
        }
    }
    if outcome.divergence.is_some() {
        exit::ERROR
    } else {
        exit::OK
    }
}
