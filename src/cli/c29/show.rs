//! How `rigscript c29` shows I/O bytes to people: hex, binary under channel numbers, and the
//! channels that are set, by name.

/// The channel numbers over the binary column of [`byte_row`].
pub fn bit_header() -> String {
    format!("{:<5} {:<4}  76543210", "", "")
}

/// The set channels of `byte` as names (`DI0 DI2`), or `none`.
pub fn channel_names(byte: u8, prefix: &str) -> String {
    let names: Vec<String> = set_channels(byte)
        .into_iter()
        .map(|ch| format!("{prefix}{ch}"))
        .collect();
    if names.is_empty() {
        "none".to_string()
    } else {
        names.join(" ")
    }
}

/// The set channels of `byte`, lowest first.
pub fn set_channels(byte: u8) -> Vec<u8> {
    (0u8..8).filter(|ch| byte & (1 << ch) != 0).collect()
}

/// One byte as a row: `DI    0x05  00000101  energized: DI0 DI2`.
pub fn byte_row(label: &str, byte: u8, word: &str, prefix: &str) -> String {
    format!(
        "{label:<5} 0x{byte:02X}  {byte:08b}  {word}: {}",
        channel_names(byte, prefix)
    )
}

/// A header and rows of [`byte_row`]s, each line ended.
pub fn byte_table(rows: &[String]) -> String {
    let mut text = bit_header();
    text.push('\n');
    for row in rows {
        text.push_str(row);
        text.push('\n');
    }
    text
}

/// A time in the module's 0.1 s steps, in seconds: `1.5 s`.
pub fn tenths(tenths: u8) -> String {
    format!("{}.{} s", tenths / 10, tenths % 10)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rows_show_hex_binary_under_channel_numbers_and_names() {
        let table = byte_table(&[
            byte_row("DI", 0x05, "energized", "DI"),
            byte_row("DO", 0x00, "on", "DO"),
        ]);
        assert_eq!(
            table,
            "            76543210\n\
             DI    0x05  00000101  energized: DI0 DI2\n\
             DO    0x00  00000000  on: none\n"
        );
        let lines: Vec<&str> = table.lines().collect();
        // Channel 0 sits over the last binary digit.
        let zero = lines[0].find('0').unwrap();
        assert_eq!(&lines[1][zero..=zero], "1");
        assert_eq!(&lines[1][zero - 2..=zero - 2], "1", "channel 2");
    }

    #[test]
    fn set_channels_lowest_first() {
        assert_eq!(set_channels(0xA1), vec![0, 5, 7]);
        assert!(set_channels(0).is_empty());
        assert_eq!(channel_names(0x80, "DO"), "DO7");
    }

    #[test]
    fn tenths_in_seconds() {
        assert_eq!(tenths(15), "1.5 s");
        assert_eq!(tenths(5), "0.5 s");
        assert_eq!(tenths(255), "25.5 s");
    }
}
