//! CRC-16/MODBUS sealing and checking of RTU frames, and the RTU silence gap (section 9).

use crate::link::line::FrameGap;
use crate::protocol::c29u::{frame_gap, Protocol};
use std::time::Duration;

/// The CRC engine of every RTU frame (CRC-16/MODBUS: poly 0x8005 reflected, init 0xFFFF).
pub const MODBUS_CRC: crc::Crc<u16> = crc::Crc::<u16>::new(&crc::CRC_16_MODBUS);

/// Shortest frame the reader considers: ID, function code and the two CRC bytes (9-1).
pub const MIN_FRAME_LEN: usize = 4;

/// Longest RTU frame (the Modbus serial-line limit); nothing longer is ever a frame.
pub const MAX_FRAME_LEN: usize = 256;

/// CRC-16/MODBUS of `bytes`.
pub fn crc16(bytes: &[u8]) -> u16 {
    MODBUS_CRC.checksum(bytes)
}

/// `body` followed by its CRC, low byte first.
pub fn seal(body: &[u8]) -> Vec<u8> {
    let mut frame = Vec::with_capacity(body.len().saturating_add(2));
    frame.extend_from_slice(body);
    seal_in_place(frame)
}

/// `body` with its CRC appended, in the same buffer.
pub fn seal_in_place(mut body: Vec<u8>) -> Vec<u8> {
    let crc = crc16(&body);
    body.extend_from_slice(&crc.to_le_bytes());
    body
}

/// The body of `frame` (without its CRC) when it is long enough and its CRC is right.
pub fn open_frame(frame: &[u8]) -> Option<&[u8]> {
    if frame.len() < MIN_FRAME_LEN {
        return None;
    }
    let (body, crc) = frame.split_last_chunk::<2>()?;
    (crc16(body) == u16::from_le_bytes(*crc)).then_some(body)
}

/// True when `frame` ends in the right CRC of what precedes it.
pub(crate) fn crc_ok(frame: &[u8]) -> bool {
    open_frame(frame).is_some()
}

/// The silence that ends a frame (t3.5): the frame-gap rule's `Auto` for Modbus.
pub fn silence_gap(baud: u32) -> Duration {
    frame_gap(Protocol::Modbus, FrameGap::Auto, baud)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn well_known_crc_vectors() {
        // The classic "read one holding register" request and its CRC 84 0A on the wire.
        assert_eq!(
            seal(&[0x01, 0x03, 0x00, 0x00, 0x00, 0x01]),
            [0x01, 0x03, 0x00, 0x00, 0x00, 0x01, 0x84, 0x0A]
        );
        // The catalogue check value of CRC-16/MODBUS.
        assert_eq!(crc16(b"123456789"), 0x4B37);
        // Another widely quoted frame: read 2 registers from 0x006B of slave 0x11 -> CRC 76 87.
        assert_eq!(
            seal(&[0x11, 0x03, 0x00, 0x6B, 0x00, 0x03]),
            [0x11, 0x03, 0x00, 0x6B, 0x00, 0x03, 0x76, 0x87]
        );
    }

    #[test]
    fn open_checks_crc_and_length() {
        let frame = seal(&[0x01, 0x46, 0x2F, 0x00]);
        assert_eq!(open_frame(&frame), Some(&[0x01, 0x46, 0x2F, 0x00][..]));
        let mut bad = frame.clone();
        bad[2] ^= 0x01;
        assert_eq!(open_frame(&bad), None);
        assert_eq!(open_frame(&[]), None);
        assert_eq!(open_frame(&[0xFF, 0xFF, 0xFF]), None);
    }

    #[test]
    fn silence_gap_is_three_and_a_half_characters() {
        assert_eq!(silence_gap(9600), Duration::from_nanos(3_645_833));
        assert_eq!(silence_gap(19_200), Duration::from_nanos(1_822_916));
        assert_eq!(silence_gap(1200), Duration::from_nanos(29_166_666));
        assert_eq!(silence_gap(38_400), Duration::from_micros(1750));
        assert_eq!(silence_gap(115_200), Duration::from_micros(1750));
        assert_eq!(silence_gap(0), Duration::from_secs(35));
    }
}
