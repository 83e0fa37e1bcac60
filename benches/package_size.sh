#!/bin/sh
# The sizes of what a release ships, against their bounds: the release binary (what `cargo
# install` ships, at most 12 MiB) and the Debian package (at most 6 MiB). A benchmark, not a test:
# the test suite packages its own debug binary (tests/debian_package.rs) and makes no release.
#
# Run from the crate root: sh benches/package_size.sh  (builds the release package with
# packaging/deb/build; RIGSCRIPT_BIN=path and CARGO_TARGET_DIR=dir package that binary instead,
# as the smoke pass does). Needs what packaging/deb/build needs (cargo-deb, xz).
set -eu
deb=$(sh packaging/deb/build | tail -n 1)
bin=${CARGO_TARGET_DIR:-target}/release/rigscript
mib() { awk -v b="$1" 'BEGIN { printf "%.2f MiB", b / 1048576 }'; }
binary=$(wc -c <"$bin")
package=$(wc -c <"$deb")
echo "binary:  $(mib "$binary") (bound 12 MiB)  $bin"
echo "package: $(mib "$package") (bound 6 MiB)  $deb"
