//! The `rigscript` command: parses the command line and hands over to `rigscript::main`.

/// Counts the heap in use, so a run can hold a script to its memory limit (`heap`).
#[global_allocator]
static HEAP: rigscript::heap::CountingAlloc = rigscript::heap::CountingAlloc;

fn main() {
    std::process::exit(rigscript::main());
}
