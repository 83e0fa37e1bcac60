//! A script's content hash: what the log, the records and `status` name a script by, so two
//! runs (or a reload's before and after) can be told apart whatever the file is called.

/// The SHA-256 of `text`, in lower-case hex.
pub fn content_hash(text: &str) -> String {
    let digest = ring::digest::digest(&ring::digest::SHA256, text.as_bytes());
    digest.as_ref().iter().map(|b| format!("{b:02x}")).collect()
}

/// The first 12 hex digits of a content hash: enough to tell scripts apart in a log line.
pub fn short(hash: &str) -> &str {
    hash.get(..12).unwrap_or(hash)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_hash_is_sha256_of_the_text() {
        assert_eq!(
            content_hash(""),
            "e3b0c44298fc1c149afbf4c8996fb92427ae41e4649b934ca495991b7852b855"
        );
        assert_ne!(content_hash("a"), content_hash("b"));
        assert_eq!(short(&content_hash("")), "e3b0c44298fc");
    }
}
