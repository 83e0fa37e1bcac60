//! `rigscript man [--out DIR]`: manual pages from the same clap definitions as the command line
//! itself (clap_mangen): `rigscript.1` on standard output, or with `--out` one page per
//! command and subcommand (`rigscript.1`, `rigscript-run.1`, `rigscript-sim-c29u.1`, ...).

use clap::{Args, CommandFactory};
use std::path::{Path, PathBuf};

/// Options of `rigscript man`.
#[derive(Debug, Args)]
#[command(
    after_help = "Install for your user: rigscript man --out ~/.local/share/man/man1 \
    (then `man rigscript`, `man rigscript-run`); system-wide: \
    sudo rigscript man --out /usr/local/share/man/man1. Read one without installing: \
    rigscript man | man -l -"
)]
pub struct ManArgs {
    /// Write every page into this directory (created if missing) instead of printing
    /// rigscript.1
    #[arg(long, value_name = "DIR")]
    pub out: Option<PathBuf>,
}

/// Writes every page into `dir`; returns the files written, in name order.
pub fn write_pages(dir: &Path) -> std::io::Result<Vec<PathBuf>> {
    std::fs::create_dir_all(dir)?;
    clap_mangen::generate_to(super::Cli::command(), dir)?;
    let mut written: Vec<PathBuf> = std::fs::read_dir(dir)?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.file_name()
                .and_then(|n| n.to_str())
                .is_some_and(|n| n.starts_with("rigscript") && n.ends_with(".1"))
        })
        .collect();
    written.sort();
    Ok(written)
}

/// The top page, `rigscript.1`, as roff.
pub fn top_page() -> std::io::Result<Vec<u8>> {
    let mut out = Vec::new();
    clap_mangen::Man::new(super::Cli::command()).render(&mut out)?;
    Ok(out)
}

/// Runs `rigscript man`; returns the exit status.
pub fn run(args: ManArgs) -> i32 {
    use std::io::Write;
    let result = match &args.out {
        Some(dir) => write_pages(dir).map(|files| {
            for f in files {
                println!("{}", f.display());
            }
        }),
        None => top_page().and_then(|page| std::io::stdout().lock().write_all(&page)),
    };
    match result {
        Ok(()) => super::output::EXIT_OK,
        Err(e) => {
            let place = args.out.as_ref().map_or_else(
                || "standard output".to_string(),
                |d| d.display().to_string(),
            );
            eprintln!("rigscript man: cannot write the manual pages to {place}: {e}");
            super::output::EXIT_FAILED
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_command_gets_a_page_with_its_name_section() {
        let dir = std::env::temp_dir().join(format!("rigscript-man-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        let written = write_pages(&dir).unwrap();
        let names: Vec<String> = written
            .iter()
            .map(|p| p.file_name().unwrap().to_string_lossy().into_owned())
            .collect();
        for page in [
            "rigscript.1",
            "rigscript-run.1",
            "rigscript-sim-c29u.1",
            "rigscript-man.1",
        ] {
            assert!(
                names.iter().any(|n| n == page),
                "{page} missing from {names:?}"
            );
        }
        for path in &written {
            let roff = std::fs::read_to_string(path).unwrap();
            assert!(roff.contains(".TH "), "{}", path.display());
            assert!(roff.contains(".SH NAME"), "{}", path.display());
        }
        std::fs::remove_dir_all(&dir).unwrap();
        let top = String::from_utf8(top_page().unwrap()).unwrap();
        assert!(top.contains(".TH rigscript 1"), "{top}");
        assert!(top.contains("rigscript\\-run(1)"), "{top}");
    }
}
