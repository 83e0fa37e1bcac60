//! Framing shared by requests and answers: hex digits, the sum checksum (section 7) and the CR.

/// Carriage return: the end of every frame (section 6).
pub const CR: u8 = b'\r';

/// Section 7's checksum: the low byte of the sum of every character before it (`$06M` is
/// `D7`; the manual's `A1` leaves out the `6`).
pub fn checksum(bytes: &[u8]) -> u8 {
    bytes.iter().fold(0u8, |sum, b| sum.wrapping_add(*b))
}

/// Why a frame's checksum was refused.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(crate) struct ChecksumFault {
    /// The checksum of the characters before the last two.
    pub expected: u8,
    /// The last two characters read as hex, or `None` when they are not hex digits.
    pub got: Option<u8>,
}

/// Appends the checksum (when enabled) and the CR to a frame's characters.
pub(crate) fn close(mut body: Vec<u8>, with_checksum: bool) -> Vec<u8> {
    if with_checksum {
        let sum = checksum(&body);
        push_hex(&mut body, sum);
    }
    body.push(CR);
    body
}

/// Removes one trailing CR and, when enabled, checks and removes the two checksum characters.
pub(crate) fn open(frame: &[u8], with_checksum: bool) -> Result<&[u8], ChecksumFault> {
    let frame = frame.strip_suffix(&[CR]).unwrap_or(frame);
    if !with_checksum {
        return Ok(frame);
    }
    match frame {
        [body @ .., hi, lo] => {
            let expected = checksum(body);
            let got = hex_pair(*hi, *lo);
            if got == Some(expected) {
                Ok(body)
            } else {
                Err(ChecksumFault { expected, got })
            }
        }
        _ => Err(ChecksumFault {
            expected: checksum(frame),
            got: None,
        }),
    }
}

/// Appends `value` as two upper-case hex digits.
pub(crate) fn push_hex(out: &mut Vec<u8>, value: u8) {
    const DIGITS: &[u8; 16] = b"0123456789ABCDEF";
    for nibble in [value >> 4, value & 0x0F] {
        if let Some(d) = DIGITS.get(usize::from(nibble)) {
            out.push(*d);
        }
    }
}

/// One hex digit, either case (answers may use lower-case hex).
pub(crate) fn hex_digit(c: u8) -> Option<u8> {
    match c {
        b'0'..=b'9' => Some(c - b'0'),
        b'A'..=b'F' => Some(c - b'A' + 10),
        b'a'..=b'f' => Some(c - b'a' + 10),
        _ => None,
    }
}

/// Two hex digits as one byte.
pub(crate) fn hex_pair(hi: u8, lo: u8) -> Option<u8> {
    Some((hex_digit(hi)? << 4) | hex_digit(lo)?)
}

/// Exactly two hex digits as one byte.
pub(crate) fn hex_byte(chars: &[u8]) -> Option<u8> {
    match chars {
        [hi, lo] => hex_pair(*hi, *lo),
        _ => None,
    }
}

/// Exactly four hex digits as a 16-bit value.
pub(crate) fn hex_u16(chars: &[u8]) -> Option<u16> {
    match chars {
        [a, b, c, d] => Some(u16::from_be_bytes([hex_pair(*a, *b)?, hex_pair(*c, *d)?])),
        _ => None,
    }
}

/// Exactly five decimal digits as a value up to 65535.
pub(crate) fn decimal_u16(chars: &[u8]) -> Option<u16> {
    if chars.len() != 5 {
        return None;
    }
    let mut value: u32 = 0;
    for c in chars {
        let digit = match c {
            b'0'..=b'9' => u32::from(c - b'0'),
            _ => return None,
        };
        value = value.checked_mul(10)?.checked_add(digit)?;
    }
    u16::try_from(value).ok()
}

/// Printable ASCII, space included: what names and firmware text may hold.
pub(crate) fn is_printable(c: u8) -> bool {
    (0x20..=0x7E).contains(&c)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn checksum_follows_the_rule_not_the_manuals_worked_example() {
        // Section 7: the rule gives D7; the manual's A1 is the sum without the '6'.
        assert_eq!(checksum(b"$06M"), 0xD7);
        assert_eq!(checksum(b"$0M"), 0xA1, "the manual's example dropped the 6");
        assert_eq!(close(b"$06M".to_vec(), true), b"$06MD7\r");
    }

    #[test]
    fn open_checks_and_strips_the_checksum_in_either_case() {
        assert_eq!(open(b"$06MD7\r", true), Ok(&b"$06M"[..]));
        assert_eq!(open(b"$06Md7\r", true), Ok(&b"$06M"[..]));
        assert_eq!(open(b"$06MD7", true), Ok(&b"$06M"[..]), "CR optional");
        assert_eq!(
            open(b"$06MA1\r", true),
            Err(ChecksumFault {
                expected: 0xD7,
                got: Some(0xA1)
            })
        );
        assert_eq!(
            open(b"$\r", true),
            Err(ChecksumFault {
                expected: b'$',
                got: None
            })
        );
        assert!(open(b"\r", true).is_err());
        assert_eq!(open(b"$06M\r", false), Ok(&b"$06M"[..]));
    }

    #[test]
    fn number_helpers() {
        assert_eq!(hex_byte(b"0a"), Some(0x0A));
        assert_eq!(hex_byte(b"0G"), None);
        assert_eq!(hex_byte(b"0"), None);
        assert_eq!(hex_u16(b"001B"), Some(0x1B));
        assert_eq!(decimal_u16(b"00023"), Some(23));
        assert_eq!(decimal_u16(b"65535"), Some(65535));
        assert_eq!(decimal_u16(b"65536"), None);
        assert_eq!(decimal_u16(b"0002A"), None);
        let mut v = Vec::new();
        push_hex(&mut v, 0xA8);
        assert_eq!(v, b"A8");
    }
}
