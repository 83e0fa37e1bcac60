//! "Did you mean" suggestions: the nearest of the names that exist to one that does not, by
//! edit distance (a slip of the keyboard, not a different word). `check` uses it for the
//! script API, rig.toml for its keys.

/// Optimal string alignment distance (Levenshtein with transpositions), for suggestions:
/// strsim's, the crate clap already brings for its own did-you-mean.
pub fn edit_distance(a: &str, b: &str) -> usize {
    strsim::osa_distance(a, b)
}

/// The closest of `candidates` to `name`, if close enough to be a slip of the keyboard.
pub fn closest<'c>(name: &str, candidates: impl IntoIterator<Item = &'c str>) -> Option<&'c str> {
    let allowed = (name.chars().count() / 3).clamp(1, 3);
    candidates
        .into_iter()
        .filter(|c| *c != name)
        .map(|c| (edit_distance(name, c), c))
        .filter(|(d, _)| *d <= allowed)
        .min()
        .map(|(_, c)| c)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_nearest_name_within_a_slip_of_the_keyboard() {
        assert_eq!(
            closest("set_outptu", ["set_output", "output"]),
            Some("set_output")
        );
        assert_eq!(closest("outputz", ["output", "outputs"]), Some("output"));
        assert_eq!(closest("zzz", ["set_output", "print"]), None);
        assert_eq!(closest("prnt", ["print"]), Some("print"));
        assert_eq!(
            closest("timout", ["period", "timeout", "retries"]),
            Some("timeout")
        );
        assert_eq!(edit_distance("ab", "ba"), 1, "a transposition is one edit");
        assert_eq!(edit_distance("", "abc"), 3);
    }
}
