//! What a newcomer meets at the command line: durations that need a unit, IDs out of range as
//! usage errors, a rig.toml without devices, shell completions that a shell accepts, and
//! manual pages that `man` renders.

use crate::common::{require_tool, rigscript, stderr, stdout, TempDir};
use std::path::PathBuf;
use std::process::{Command, Output, Stdio};

fn run(args: &[&str]) -> Output {
    Command::new(rigscript())
        .args(args)
        .stdin(Stdio::null())
        .output()
        .unwrap()
}

#[test]
fn a_duration_without_a_unit_is_refused_with_the_forms_that_work() {
    let d = TempDir::new("durations");
    let script = d.file("s.rhai", "after(\"50ms\", || stop());\n");
    for (flag, value) in [("--for", "10"), ("--period", "20")] {
        let o = run(&["run", "--sim", flag, value, &script]);
        let err = stderr(&o);
        assert_eq!(o.status.code(), Some(2), "{flag} {value}: {err}");
        assert!(
            err.contains(&format!(
                "\"{value}\" has no unit: write \"{value}ms\", \"{value}s\" or \"{value}m\" (a \
                 duration is a number with a unit (\"250us\", \"20ms\", \"1.5s\", \"5m\", \"2h\", \
                 \"1h30m\"))"
            )),
            "{err}"
        );
    }
    let o = run(&["run", "--help"]);
    let help = stdout(&o);
    assert!(help.contains("a bare number is refused"), "{help}");
    assert!(!help.contains("or milliseconds"), "{help}");
    // Flags named in milliseconds keep plain numbers.
    let o = run(&["c29", "--help"]);
    assert!(stdout(&o).contains("--timeout <MS>"), "{}", stdout(&o));
    // Numbers in scripts are still milliseconds: that is the script API.
    let o = run(&["run", "--sim", "--for", "1s", &script]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
}

#[test]
fn sim_ids_out_of_range_are_usage_errors_alike() {
    for id in ["0", "300", "248"] {
        let o = run(&["sim", "c29u", "--id", id]);
        let err = stderr(&o);
        assert_eq!(o.status.code(), Some(2), "--id {id}: {err}");
        assert!(
            err.starts_with(&format!(
                "error: invalid value '{id}' for '--id <ID>': `{id}` is not"
            )),
            "{err}"
        );
        assert!(
            err.contains("Modbus RTU modules take IDs 1-247, ASCII modules 0-255"),
            "{err}"
        );
        assert!(stdout(&o).is_empty(), "no pty was served: {}", stdout(&o));
    }
}

#[test]
fn a_config_without_devices_under_sim_says_so() {
    let d = TempDir::new("no-devices");
    let config = d.file("rig.toml", "period = \"20ms\"\n");
    let script = d.file("s.rhai", "io.outputs = 1;\n");
    let o = run(&["run", "--sim", "--config", &config, "--for", "1s", &script]);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(2), "{err}");
    assert!(err.contains("the config defines no devices"), "{err}");
    assert!(
        err.contains("--sim without --config gives the default rig: panel (a TRC1000) and io"),
        "{err}"
    );
    assert!(!err.contains("(devices: )"), "{err}");
}

#[test]
fn bash_accepts_the_completion_script_and_it_completes_subcommands() {
    require_tool("bash", "bash");
    let d = TempDir::new("completions");
    let o = run(&["completions", "bash"]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let file = d.file("rigscript.bash", &stdout(&o));
    // Load it as bash-completion would, then ask for the words after `rigscript `.
    let probe = format!(
        "source {file} && complete -p rigscript && COMP_WORDS=(rigscript '') COMP_CWORD=1 \
         COMP_LINE='rigscript ' COMP_POINT=10 && _rigscript rigscript '' rigscript && \
         printf '%s\\n' \"${{COMPREPLY[@]}}\""
    );
    let o = Command::new("bash").args(["-c", &probe]).output().unwrap();
    let out = stdout(&o);
    assert_eq!(o.status.code(), Some(0), "{out}{}", stderr(&o));
    for sub in [
        "run",
        "check",
        "test",
        "scan",
        "c29",
        "trc",
        "sim",
        "completions",
        "man",
    ] {
        assert!(out.lines().any(|l| l == sub), "no {sub} in:\n{out}");
    }
    for shell in ["zsh", "fish"] {
        let o = run(&["completions", shell]);
        assert_eq!(o.status.code(), Some(0), "{shell}: {}", stderr(&o));
        assert!(stdout(&o).contains("completions"), "{shell}");
    }
    let o = run(&["completions", "tcsh"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(
        stderr(&o).contains("[possible values: bash"),
        "{}",
        stderr(&o)
    );
}

#[test]
#[ignore = "needs man-db (tier 2: .ci/run installs it)"]
fn man_renders_every_page_it_writes() {
    require_tool("man", "man-db");
    let d = TempDir::new("man");
    let out = d.root().join("man1");
    let o = run(&["man", "--out", out.to_str().unwrap()]);
    assert_eq!(o.status.code(), Some(0), "{}", stderr(&o));
    let pages: Vec<String> = stdout(&o).lines().map(str::to_string).collect();
    assert!(pages.len() >= 10, "{pages:?}");
    for page in &pages {
        let o = Command::new("man")
            .args(["-l", "-P", "cat", page])
            .env("MANWIDTH", "100")
            .output()
            .unwrap();
        let text = stdout(&o);
        assert_eq!(o.status.code(), Some(0), "{page}: {}", stderr(&o));
        assert!(text.contains("NAME"), "{page}:\n{text}");
        assert!(text.contains("SYNOPSIS"), "{page}:\n{text}");
    }
    let run_page = pages
        .iter()
        .find(|p| p.ends_with("rigscript-run.1"))
        .unwrap();
    let o = Command::new("man")
        .args(["-l", "-P", "cat", run_page])
        .env("MANWIDTH", "200")
        .output()
        .unwrap();
    let text = stdout(&o);
    assert!(text.contains("rigscript-run - Run a script"), "{text}");
    assert!(text.contains("--wake-latency"), "{text}");
    // Without --out, the top page goes to standard output.
    let o = run(&["man"]);
    assert!(stdout(&o).contains(".SH NAME"), "{}", stdout(&o));
}

#[test]
fn the_license_file_is_the_license_cargo_toml_names() {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR"));
    let manifest = std::fs::read_to_string(root.join("Cargo.toml")).unwrap();
    assert!(manifest.contains("\nlicense = \"MIT\"\n"), "{manifest}");
    let license = std::fs::read_to_string(root.join("LICENSE")).unwrap();
    assert!(license.starts_with("MIT License\n"), "{license}");
    assert!(license.contains("Permission is hereby granted, free of charge"));
}

/// Standard output whose reader has already gone, as `rigscript ... | head -0` leaves it.
fn closed_stdout() -> Stdio {
    let mut fds = [0; 2];
    // SAFETY: pipe() fills the two descriptors; the read end is closed at once and the write
    // end is owned by the Stdio from then on.
    unsafe {
        assert_eq!(libc::pipe(fds.as_mut_ptr()), 0);
        libc::close(fds[0]);
        Stdio::from(<std::os::fd::OwnedFd as std::os::fd::FromRawFd>::from_raw_fd(fds[1]))
    }
}

#[test]
fn a_report_whose_reader_went_away_ends_as_grep_would_and_a_run_keeps_its_status() {
    use std::os::unix::process::ExitStatusExt;
    let d = TempDir::new("closed-stdout");
    let script = d.file("s.rhai", "after(\"50ms\", || stop());\n");
    let reports: [&[&str]; 3] = [
        &["completions", "bash"],
        &["man"],
        &["check", script.as_str()],
    ];
    for args in reports {
        let o = Command::new(rigscript())
            .args(args)
            .stdin(Stdio::null())
            .stdout(closed_stdout())
            .output()
            .unwrap();
        let err = stderr(&o);
        assert_eq!(o.status.signal(), Some(libc::SIGPIPE), "{args:?}: {err}");
        assert!(!err.contains("panicked"), "{args:?}: {err}");
    }
    // A run goes to its end whatever became of standard output: its status is the run's.
    let o = Command::new(rigscript())
        .args(["run", "--sim", "--stats", &script])
        .stdin(Stdio::null())
        .stdout(closed_stdout())
        .output()
        .unwrap();
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(0), "{err}");
    assert!(err.contains("safe state (stop())"), "{err}");
    assert!(!err.contains("panicked"), "{err}");
}

#[test]
fn api_shows_the_script_reference_in_the_terminal() {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_rigscript"))
        .args(["api", "every"])
        .output()
        .unwrap();
    let text = stdout(&out);
    assert_eq!(out.status.code(), Some(0), "{text}");
    assert!(text.starts_with("every(dur, |missed| ..)"), "{text}");
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_rigscript"))
        .args(["api", "evry"])
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(stderr(&out).contains("did you mean `every`?"), "{out:?}");
}
