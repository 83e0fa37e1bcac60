//! `rigscript completions SHELL`: the shell's completion script for rigscript, from the same
//! clap definitions as the command line itself (clap_complete), on standard output.

use clap::{Args, CommandFactory};
use clap_complete::Shell;

/// Options of `rigscript completions`.
#[derive(Debug, Args)]
#[command(after_help = "Install (each shell looks in its own place):\n  \
    bash: rigscript completions bash > ~/.local/share/bash-completion/completions/rigscript\n  \
    zsh:  rigscript completions zsh > ~/.zfunc/_rigscript   (with fpath+=~/.zfunc before compinit in ~/.zshrc)\n  \
    fish: rigscript completions fish > ~/.config/fish/completions/rigscript.fish")]
pub struct CompletionsArgs {
    /// The shell to complete in.
    #[arg(value_enum)]
    pub shell: Shell,
}

/// Writes the completion script for `args.shell` to `out`.
pub fn write(args: &CompletionsArgs, out: &mut dyn std::io::Write) {
    let mut cmd = super::Cli::command();
    clap_complete::generate(args.shell, &mut cmd, "rigscript", out);
}

/// Runs `rigscript completions`; returns the exit status.
pub fn run(args: CompletionsArgs) -> i32 {
    write(&args, &mut std::io::stdout().lock());
    super::output::EXIT_OK
}

#[cfg(test)]
mod tests {
    use super::*;

    fn script(shell: Shell) -> String {
        let mut out = Vec::new();
        write(&CompletionsArgs { shell }, &mut out);
        String::from_utf8(out).unwrap()
    }

    #[test]
    fn each_script_names_every_subcommand() {
        let cmd = crate::cli::Cli::command();
        let names: Vec<&str> = cmd.get_subcommands().map(|c| c.get_name()).collect();
        assert!(
            names.contains(&"completions") && names.contains(&"man"),
            "{names:?}"
        );
        for shell in [Shell::Bash, Shell::Zsh, Shell::Fish] {
            let text = script(shell);
            for name in &names {
                assert!(text.contains(name), "{shell}: no {name}");
            }
            // Options of a subcommand and of a sub-subcommand are there too.
            assert!(text.contains("wake-latency"), "{shell}");
            assert!(text.contains("checksum"), "{shell}");
        }
    }
}
