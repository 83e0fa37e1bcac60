//! Cuts RTU frames out of a byte stream that arrives in arbitrary pieces, without trusting
//! frame lengths to be known in advance (manual section 10: vendor 46 lengths are unreliable).
//!
//! A frame ends on a valid CRC or on silence, whichever the reader can tell first. What the
//! first bytes say about the frame's length decides how far a CRC is trusted: a length fixed by
//! the function code (or by a byte count) is checked alone, so a short prefix that happens to
//! have a valid CRC (1 in 65536 per candidate) is never taken for a frame; only where the length
//! is uncertain are other lengths tried. Time is the caller's: it measures the silence (see
//! `silence_gap`) and calls `end_of_silence`.

use super::frame::{crc_ok, MAX_FRAME_LEN, MIN_FRAME_LEN, MODBUS_CRC};
use super::request::{vendor_answer_len, vendor_request_len, Request};
use super::response::{is_output_write, is_safe_mode_function};
use super::{EXCEPTION_FLAG, FC_VENDOR};

/// What the master knows about the answer it waits for: only frames that could be that answer
/// (or its exception) are considered, and the expected length is tried first.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Expectation {
    /// The slave the request went to (it answers from that ID, even after 46 04).
    pub id: u8,
    /// The request's function code.
    pub function: u8,
    /// The request's vendor sub-function, for 46.
    pub sub: Option<u8>,
    /// The expected length of the normal answer, CRC included, when known.
    pub length: Option<usize>,
}

impl Expectation {
    /// The answer to `request` sent to slave `id`.
    pub fn answer_to(id: u8, request: &Request) -> Self {
        Self {
            id,
            function: request.function(),
            sub: request.vendor_sub(),
            length: request.answer_len(),
        }
    }
}

/// Which direction of traffic the reader frames.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Side {
    /// Requests, as a slave (the simulator) sees them.
    Requests,
    /// Answers, as the master sees them; tighter when it knows what it waits for.
    Answers(Option<Expectation>),
}

/// What the first bytes of the buffer say about a frame starting there.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Shape {
    /// Too few bytes to tell.
    NeedMore,
    /// No frame of this side can start here.
    Impossible,
    /// The length is fixed by the function code or a byte count.
    Exact(usize),
    /// Probably this long, but the module may send another length.
    Expected(usize),
    /// Nothing known: the first CRC-valid prefix ends it.
    Unknown,
}

impl Shape {
    /// Lengths above the RTU limit cannot be frames.
    fn bounded(self) -> Self {
        match self {
            Self::Exact(l) | Self::Expected(l) if l > MAX_FRAME_LEN => Self::Impossible,
            other => other,
        }
    }
}

/// What to do with the bytes at the start of the buffer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Step {
    /// A frame of this length is complete.
    Emit(usize),
    /// No frame starts at the first byte (or it is corrupt): drop bytes to resynchronise.
    Skip(usize),
    /// Wait for more bytes (or for silence).
    Wait,
}

/// Splits a byte stream into Modbus RTU frames; one mechanism for both directions.
///
/// The buffer never holds more than the bytes of one frame that may still be arriving (fewer
/// than [`MAX_FRAME_LEN`]) plus one piece of input, so a flooding peer cannot grow it, and the
/// work per byte is bounded: whether a complete frame of certain length starts at an offset is
/// decided once per offset (`Verdict`), however many times the search passes over it.
#[derive(Debug, Clone)]
pub struct FrameReader {
    buf: Vec<u8>,
    /// One entry per byte of `buf`: what is known about a frame of certain length starting there.
    verdicts: Vec<Verdict>,
    side: Side,
    discarded: u64,
}

/// Whether a complete frame of certain length (and valid CRC) starts at an offset of the buffer.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Verdict {
    /// Not known yet: the frame there is not complete.
    Open,
    /// No such frame starts there, whatever bytes follow.
    No,
    /// One does.
    Yes,
}

/// The search for the next later frame during one pass over an unchanged buffer: offsets before
/// `next` have been looked at in this pass, and `found` is the first hit among them.
#[derive(Debug, Default)]
struct Search {
    next: usize,
    found: Option<usize>,
}

impl FrameReader {
    /// A reader of requests, for a slave (the simulator).
    pub fn for_requests() -> Self {
        Self::new(Side::Requests)
    }

    /// A reader of answers, for the master, with no expectation yet.
    pub fn for_answers() -> Self {
        Self::new(Side::Answers(None))
    }

    fn new(side: Side) -> Self {
        Self {
            buf: Vec::new(),
            verdicts: Vec::new(),
            side,
            discarded: 0,
        }
    }

    /// Tells an answer reader which answer comes next (call before sending `request`).
    /// Ignored by a request reader.
    pub fn expect_answer(&mut self, id: u8, request: &Request) {
        if let Side::Answers(e) = &mut self.side {
            *e = Some(Expectation::answer_to(id, request));
            self.forget_verdicts();
        }
    }

    /// Forgets the expectation: any well-formed answer is taken.
    pub fn clear_expectation(&mut self) {
        if let Side::Answers(e) = &mut self.side {
            *e = None;
            self.forget_verdicts();
        }
    }

    /// Takes bytes as they arrive and returns the frames they complete, in order, CRC included.
    pub fn push(&mut self, bytes: &[u8]) -> Vec<Vec<u8>> {
        let mut frames = Vec::new();
        // A piece at a time, so the buffer stays bounded however much arrives at once.
        for piece in bytes.chunks(MAX_FRAME_LEN) {
            self.buf.extend_from_slice(piece);
            self.verdicts.resize(self.buf.len(), Verdict::Open);
            self.parse(&mut frames);
        }
        frames
    }

    /// Cuts every frame it can out of the buffer, then drops what was used or skipped.
    fn parse(&mut self, frames: &mut Vec<Vec<u8>>) {
        let mut start = 0;
        let mut search = Search::default();
        while start < self.buf.len() {
            match self.step(start, &mut search) {
                Step::Emit(len) => {
                    frames.extend(self.buf.get(start..start + len).map(<[u8]>::to_vec));
                    start += len;
                }
                Step::Skip(n) => {
                    let n = n.clamp(1, self.buf.len() - start);
                    self.discarded = self.discarded.saturating_add(n as u64);
                    start += n;
                }
                Step::Wait => break,
            }
        }
        self.buf.drain(..start);
        self.verdicts.drain(..start.min(self.verdicts.len()));
    }

    /// The line has been silent for 3.5 characters: whatever is buffered is the end of a frame.
    /// Returns it when the whole of it has a valid CRC (a frame shorter than expected), and
    /// discards it otherwise. The buffer is empty afterwards.
    pub fn end_of_silence(&mut self) -> Option<Vec<u8>> {
        let buf = std::mem::take(&mut self.buf);
        self.verdicts.clear();
        if buf.len() >= MIN_FRAME_LEN && buf.len() <= MAX_FRAME_LEN && crc_ok(&buf) {
            return Some(buf);
        }
        self.discarded = self.discarded.saturating_add(buf.len() as u64);
        None
    }

    /// Drops any buffered bytes (before a new request, for instance), counting them as discarded.
    pub fn clear(&mut self) {
        self.discarded = self.discarded.saturating_add(self.buf.len() as u64);
        self.buf.clear();
        self.verdicts.clear();
    }

    /// The bytes received but not yet part of a frame.
    pub fn pending(&self) -> &[u8] {
        &self.buf
    }

    /// How many bytes have been thrown away so far (garbage, bad CRCs, cut-off frames).
    pub fn discarded(&self) -> u64 {
        self.discarded
    }

    /// A new expectation changes which frames are certain: judge every offset again.
    fn forget_verdicts(&mut self) {
        self.verdicts.fill(Verdict::Open);
    }

    /// Decides what to do with the frame that may start at `buf[start]`.
    fn step(&mut self, start: usize, search: &mut Search) -> Step {
        let Some(buf) = self.buf.get(start..) else {
            return Step::Wait;
        };
        match self.shape(buf) {
            Shape::NeedMore => Step::Wait,
            Shape::Impossible => Step::Skip(1),
            Shape::Exact(len) => match buf.get(..len) {
                None => Step::Wait,
                Some(frame) if crc_ok(frame) => Step::Emit(len),
                Some(_) => Step::Skip(1),
            },
            Shape::Expected(len) => match buf.get(..len) {
                Some(frame) if crc_ok(frame) => Step::Emit(len),
                Some(_) => self.uncertain(start, search),
                // The expected length has not arrived yet; shorter CRC matches are not
                // trusted before then (they are taken at silence, see end_of_silence).
                None => self
                    .later_frame(start, search)
                    .map_or(Step::Wait, |at| Step::Skip(at - start)),
            },
            Shape::Unknown => self.uncertain(start, search),
        }
    }

    /// A frame whose length is uncertain: the shortest CRC-valid prefix ends it; failing that,
    /// a complete frame of certain shape further on means the start was garbage.
    fn uncertain(&mut self, start: usize, search: &mut Search) -> Step {
        let rest = self.buf.get(start..).unwrap_or_default();
        if let Some(len) = first_valid_prefix(rest) {
            return Step::Emit(len);
        }
        let long_enough = rest.len() >= MAX_FRAME_LEN;
        if let Some(at) = self.later_frame(start, search) {
            return Step::Skip(at - start);
        }
        if long_enough {
            Step::Skip(1)
        } else {
            Step::Wait
        }
    }

    /// The offset (in `buf`) of the first frame after `start` whose length the reader is sure
    /// of, complete and with a valid CRC. Each offset is judged once while its verdict is final,
    /// and looked at once per pass while it is open, so a pass stays linear.
    fn later_frame(&mut self, start: usize, search: &mut Search) -> Option<usize> {
        if let Some(found) = search.found.filter(|&f| f > start) {
            return Some(found);
        }
        let mut at = search.next.max(start + 1);
        while at < self.buf.len() {
            if self.verdict(at) == Verdict::Yes {
                search.next = at + 1;
                search.found = Some(at);
                return Some(at);
            }
            at += 1;
        }
        search.next = at;
        search.found = None;
        None
    }

    /// Whether a complete frame of certain length starts at `at`; remembered once final.
    fn verdict(&mut self, at: usize) -> Verdict {
        let known = self.verdicts.get(at).copied().unwrap_or(Verdict::Open);
        if known != Verdict::Open {
            return known;
        }
        let rest = self.buf.get(at..).unwrap_or_default();
        let verdict = match self.shape(rest) {
            Shape::Exact(len) | Shape::Expected(len) => match rest.get(..len) {
                Some(frame) if crc_ok(frame) => Verdict::Yes,
                Some(_) => Verdict::No,
                None => Verdict::Open,
            },
            Shape::NeedMore => Verdict::Open,
            Shape::Impossible | Shape::Unknown => Verdict::No,
        };
        if let Some(slot) = self.verdicts.get_mut(at) {
            *slot = verdict;
        }
        verdict
    }

    fn shape(&self, buf: &[u8]) -> Shape {
        match self.side {
            Side::Requests => request_shape(buf),
            Side::Answers(None) => answer_shape(buf),
            Side::Answers(Some(e)) => expected_answer_shape(buf, e),
        }
        .bounded()
    }
}

/// The shortest prefix of `buf` (from `MIN_FRAME_LEN` up) whose CRC is valid. A frame followed
/// by its CRC (low byte first) has a CRC-16/MODBUS of zero, so one pass checks every length.
fn first_valid_prefix(buf: &[u8]) -> Option<usize> {
    let mut digest = MODBUS_CRC.digest();
    for (i, byte) in buf.iter().take(MAX_FRAME_LEN).enumerate() {
        digest.update(std::slice::from_ref(byte));
        let len = i.saturating_add(1);
        if len >= MIN_FRAME_LEN && digest.clone().finalize() == 0 {
            return Some(len);
        }
    }
    None
}

/// Requests as the module reads them. Function codes the module does not implement but whose
/// standard request length is known are framed (and answered with an exception); others,
/// including anything with bit 7 set, cannot start a request.
fn request_shape(buf: &[u8]) -> Shape {
    let Some(&function) = buf.get(1) else {
        return Shape::NeedMore;
    };
    match function {
        0x01..=0x06 | 0x08 => Shape::Exact(8),
        0x07 | 0x0B | 0x0C | 0x11 => Shape::Exact(4),
        0x0F | 0x10 => match buf.get(6) {
            Some(&bc) => Shape::Exact(9 + usize::from(bc)),
            None => Shape::NeedMore,
        },
        FC_VENDOR => match buf.get(2) {
            Some(&sub) => vendor_request_len(sub).map_or(Shape::Unknown, Shape::Expected),
            None => Shape::NeedMore,
        },
        _ => Shape::Impossible,
    }
}

/// Answers of any kind, when the master does not say what it waits for.
fn answer_shape(buf: &[u8]) -> Shape {
    let Some(&function) = buf.get(1) else {
        return Shape::NeedMore;
    };
    match function {
        0x00 => Shape::Impossible,
        f if f == FC_VENDOR | EXCEPTION_FLAG => Shape::Expected(5),
        f if f & EXCEPTION_FLAG != 0 => Shape::Exact(5),
        0x01..=0x04 => byte_count_shape(buf),
        0x05 | 0x06 | 0x0F | 0x10 => Shape::Exact(8),
        FC_VENDOR => match buf.get(2) {
            Some(&sub) => vendor_answer_len(sub).map_or(Shape::Unknown, Shape::Expected),
            None => Shape::NeedMore,
        },
        _ => Shape::Unknown,
    }
}

/// The answer (or exception) to a known request from a known slave; anything else is garbage.
fn expected_answer_shape(buf: &[u8], e: Expectation) -> Shape {
    let Some(&id) = buf.first() else {
        return Shape::NeedMore;
    };
    if id != e.id {
        return Shape::Impossible;
    }
    let Some(&function) = buf.get(1) else {
        return Shape::NeedMore;
    };
    if function == e.function | EXCEPTION_FLAG {
        // The vendor error `ID C6 00` is also written `ID C6 (CRC)` in section 10.
        return if e.function == FC_VENDOR {
            Shape::Expected(5)
        } else {
            Shape::Exact(5)
        };
    }
    if is_output_write(e.function) && is_safe_mode_function(function) {
        // 10-16: the safe-mode refusal of a 05 write may come as `ID 8F FF`.
        return Shape::Exact(5);
    }
    if function != e.function {
        return Shape::Impossible;
    }
    match function {
        0x01..=0x04 => byte_count_shape(buf),
        FC_VENDOR => match (buf.get(2), e.sub) {
            (None, _) => Shape::NeedMore,
            (Some(&sub), Some(want)) if sub != want => Shape::Impossible,
            _ => e.length.map_or(Shape::Unknown, Shape::Expected),
        },
        _ => e.length.map_or(Shape::Unknown, Shape::Exact),
    }
}

/// `ID FC BC data CRC`.
fn byte_count_shape(buf: &[u8]) -> Shape {
    match buf.get(2) {
        Some(&bc) => Shape::Exact(5 + usize::from(bc)),
        None => Shape::NeedMore,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::protocol::c29u_modbus::{
        encode_exception, encode_response, encode_vendor_error, seal, BitArea, ExceptionCode,
        Response, VendorRequest, VendorResponse,
    };

    fn read_do() -> Vec<u8> {
        Request::ReadBits(BitArea::Outputs).encode(1)
    }

    #[test]
    fn residue_of_a_sealed_frame_is_zero() {
        let f = seal(&[1, 2, 3, 4, 5]);
        assert_eq!(MODBUS_CRC.checksum(&f), 0);
        assert_eq!(first_valid_prefix(&f), Some(f.len()));
    }

    #[test]
    fn partial_reads_byte_by_byte() {
        let mut r = FrameReader::for_requests();
        let f = read_do();
        let (last, head) = f.split_last().unwrap();
        for b in head {
            assert!(r.push(&[*b]).is_empty());
        }
        assert_eq!(r.push(&[*last]), vec![f]);
        assert!(r.pending().is_empty());
        assert_eq!(r.discarded(), 0);
    }

    #[test]
    fn two_frames_back_to_back_in_one_piece() {
        let mut r = FrameReader::for_requests();
        let a = read_do();
        let b = Request::write_outputs(0x25).encode(1);
        let c = Request::Vendor(VendorRequest::HostOk).encode(1);
        let stream = [a.clone(), b.clone(), c.clone()].concat();
        assert_eq!(r.push(&stream), vec![a, b, c]);
    }

    #[test]
    fn leading_garbage_is_dropped() {
        let mut r = FrameReader::for_requests();
        let f = read_do();
        let stream = [&[0xFF, 0x00, 0x13, 0x01][..], &f].concat();
        assert_eq!(r.push(&stream), vec![f]);
        assert_eq!(r.discarded(), 4);
    }

    #[test]
    fn garbage_that_looks_like_a_vendor_request_is_dropped() {
        // `07 46 06` announces a 13-byte set-baud request; the real frame behind it is found.
        let mut r = FrameReader::for_requests();
        let f = read_do();
        let stream = [&[0x07, 0x46, 0x06][..], &f].concat();
        assert_eq!(r.push(&stream), vec![f]);
        // And an unknown sub-function (unknown length) in front of a frame.
        let f = Request::Vendor(VendorRequest::ReadName).encode(1);
        let stream = [&[0x07, 0x46, 0x77, 0x01][..], &f].concat();
        assert_eq!(r.push(&stream), vec![f]);
    }

    #[test]
    fn bad_crc_then_a_good_frame() {
        let mut r = FrameReader::for_requests();
        let mut bad = Request::write_outputs(0x11).encode(1);
        let n = bad.len();
        bad[n - 1] ^= 0x55;
        let good = read_do();
        assert!(r.push(&bad).is_empty());
        assert_eq!(r.push(&good), vec![good.clone()]);
        assert_eq!(r.discarded(), bad.len() as u64);
    }

    #[test]
    fn silence_discards_an_incomplete_frame() {
        let mut r = FrameReader::for_requests();
        let f = read_do();
        assert!(r.push(&f[..5]).is_empty());
        assert_eq!(r.end_of_silence(), None);
        assert_eq!(r.discarded(), 5);
        // The rest of the old frame after the gap is garbage; the next frame still gets through.
        let next = Request::read_counters(8).encode(1);
        assert_eq!(r.push(&[&f[5..], &next[..]].concat()), vec![next]);
    }

    #[test]
    fn unknown_length_vendor_answers() {
        // No expectation: a 46 answer with an unknown sub-function ends at its CRC.
        let mut r = FrameReader::for_answers();
        let odd = seal(&[1, 0x46, 0x77, 0x01, 0x02, 0x03]);
        let (a, b) = odd.split_at(4);
        assert!(r.push(a).is_empty());
        assert_eq!(r.push(b), vec![odd]);
    }

    #[test]
    fn vendor_answer_longer_than_expected() {
        // Waiting for the 7-byte `ID 46 0C EN WT`, the module sends a reserved byte more.
        let mut r = FrameReader::for_answers();
        let req = Request::Vendor(VendorRequest::ReadWatchdog);
        r.expect_answer(1, &req);
        let long = seal(&[1, 0x46, 0x0C, 0x01, 0x0F, 0x00]);
        assert!(r.push(&long[..7]).is_empty());
        assert_eq!(r.push(&long[7..]), vec![long]);
    }

    #[test]
    fn vendor_answer_shorter_than_expected_ends_on_silence() {
        // 10-9's format line `ID 46 0C WT`: one byte less than expected.
        let mut r = FrameReader::for_answers();
        r.expect_answer(1, &Request::Vendor(VendorRequest::ReadWatchdog));
        let short = seal(&[1, 0x46, 0x0C, 0x0F]);
        assert!(r.push(&short).is_empty());
        assert_eq!(r.end_of_silence(), Some(short));
        assert!(r.pending().is_empty());
    }

    #[test]
    fn expected_answer_skips_other_slaves_and_functions() {
        let mut r = FrameReader::for_answers();
        let req = Request::ReadBits(BitArea::Inputs);
        r.expect_answer(3, &req);
        let other = encode_response(2, &Response::Bits(0xAA));
        let mine = encode_response(3, &Response::Bits(0xDF));
        assert_eq!(r.push(&[&other[..], &mine[..]].concat()), vec![mine]);
        assert_eq!(r.discarded(), other.len() as u64);
        let exc = encode_exception(3, 0x01, ExceptionCode::Range);
        assert_eq!(r.push(&exc), vec![exc]);
    }

    #[test]
    fn vendor_error_and_safe_mode_answers() {
        let mut r = FrameReader::for_answers();
        r.expect_answer(1, &Request::Vendor(VendorRequest::SetSafeValue(0x14)));
        let e = encode_vendor_error(1);
        assert_eq!(r.push(&e), vec![e]);
        r.expect_answer(1, &Request::write_outputs(0x01));
        let e = encode_exception(1, 0x0F, ExceptionCode::SafeMode);
        assert_eq!(r.push(&e), vec![e]);
        // Unexpected sub-function from the right slave is garbage for this expectation.
        r.expect_answer(1, &Request::Vendor(VendorRequest::ReadSafeValue));
        let other = encode_response(1, &Response::Vendor(VendorResponse::PowerOnValue(3)));
        let mine = encode_response(1, &Response::Vendor(VendorResponse::SafeValue(3)));
        assert_eq!(r.push(&[&other[..], &mine[..]].concat()), vec![mine]);
    }

    #[test]
    fn a_crc_valid_short_prefix_is_not_taken_before_the_expected_length() {
        // A 9-byte name answer whose first 5 bytes happen to form a frame with a valid CRC
        // (`01 46 00` + its CRC): the reader waits for the expected length.
        let head = seal(&[0x01, 0x46, 0x00]);
        let frame = seal(&[head[0], head[1], head[2], head[3], head[4], 0x0C, 0x29]);
        assert_eq!(frame.len(), 9);
        let req = Request::Vendor(VendorRequest::ReadName);
        for expect in [false, true] {
            let mut r = FrameReader::for_answers();
            if expect {
                r.expect_answer(1, &req);
            }
            assert!(r.push(&frame[..5]).is_empty());
            assert!(r.push(&frame[5..8]).is_empty());
            assert_eq!(r.push(&frame[8..]), vec![frame.clone()]);
        }
        // Likewise a fixed-length request: `01 05 crc crc FF 00` + CRC is one 8-byte frame.
        let head = seal(&[0x01, 0x05]);
        let frame = seal(&[head[0], head[1], head[2], head[3], 0xFF, 0x00]);
        let mut r = FrameReader::for_requests();
        assert!(r.push(&frame[..4]).is_empty());
        assert_eq!(r.push(&frame[4..]), vec![frame]);
    }

    #[test]
    fn oversized_byte_counts_cannot_stall_forever() {
        let mut r = FrameReader::for_requests();
        // 0F with byte count FF: 264 bytes, above the RTU limit, so not a frame start.
        let garbage = [0x01, 0x0F, 0, 0, 0, 8, 0xFF];
        let f = read_do();
        assert_eq!(r.push(&[&garbage[..], &f[..]].concat()), vec![f]);
    }

    #[test]
    fn a_flood_leaves_a_bounded_buffer_and_the_next_frame_is_found() {
        // A peer sending `01 46 77` nonstop (a vendor request of unknown length).
        let flood = [0x01, 0x46, 0x77].repeat(40_000);
        let answer = encode_response(1, &Response::Bits(0xDF));
        let expecting = || {
            let mut r = FrameReader::for_answers();
            r.expect_answer(1, &Request::ReadBits(BitArea::Inputs));
            r
        };
        let cases = [
            (FrameReader::for_requests(), read_do()),
            (FrameReader::for_answers(), answer.clone()),
            (expecting(), answer),
        ];
        for (mut r, frame) in cases {
            for piece in [&flood[..], &flood[..7]] {
                assert!(r.push(piece).is_empty());
                assert!(r.pending().len() < MAX_FRAME_LEN, "{}", r.pending().len());
            }
            assert_eq!(r.push(&frame), vec![frame.clone()]);
            assert!(r.pending().is_empty());
            assert_eq!(r.discarded(), flood.len() as u64 + 7);
        }
    }

    #[test]
    fn a_new_expectation_judges_buffered_offsets_again() {
        // A frame from slave 1 behind a garbage byte: not the answer slave 2 is expected to send,
        // but the answer once slave 1 is expected.
        let frame = encode_response(1, &Response::Bits(0xDF));
        let mut r = FrameReader::for_answers();
        r.expect_answer(2, &Request::ReadBits(BitArea::Inputs));
        r.buf = [&[0xAA][..], &frame].concat();
        r.verdicts = vec![Verdict::Open; r.buf.len()];
        assert_eq!(r.verdict(1), Verdict::No);
        r.expect_answer(1, &Request::ReadBits(BitArea::Inputs));
        assert_eq!(r.verdict(1), Verdict::Yes);
    }

    #[test]
    fn clear_forgets_the_buffer() {
        let mut r = FrameReader::for_answers();
        r.push(&[1, 3]);
        r.clear();
        assert!(r.pending().is_empty());
        assert_eq!(r.discarded(), 2);
    }
}
