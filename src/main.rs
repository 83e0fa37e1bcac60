//! The `rigscript` command: parses the command line and hands over to `rigscript::cli`.

fn main() {
    std::process::exit(rigscript::cli::main());
}
