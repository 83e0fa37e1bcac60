//! How the Modbus `FrameReader`'s time grows with the input: floods of 4 KiB to 256 KiB, pushed
//! in one piece and in 16-byte pieces, on both sides. Linear parsing shows as a flat time per
//! byte across sizes. Run: `cargo bench --bench frame_reader`.

#[path = "common/args.rs"]
mod args;
use args::BenchArgs;
use rigscript::protocol::c29u_modbus::{
    encode_response, BitArea, FrameReader, Request, Response, MAX_FRAME_LEN,
};
use std::time::Instant;

/// Input sizes, in KiB.
const SIZES: [usize; 4] = [4, 16, 64, 256];

/// `cargo test --all-targets` runs this without `--bench`: small sizes only check it still works.
const SMOKE: [usize; 2] = [1, 2];

/// A flood made of `pattern` repeated to `len` bytes.
fn repeat(pattern: &[u8], len: usize) -> Vec<u8> {
    pattern.iter().copied().cycle().take(len).collect()
}

/// Pseudo-random bytes (xorshift), the same every run.
fn noise(len: usize) -> Vec<u8> {
    let mut x: u64 = 0x9E37_79B9_7F4A_7C15;
    (0..len)
        .map(|_| {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            x.to_le_bytes()[0]
        })
        .collect()
}

/// The floods: `01 46 77` (a vendor request of unknown length, nonstop), noise, and
/// `0F` headers announcing 255-byte frames (the longest a reader must wait for and check).
fn floods(len: usize) -> Vec<(&'static str, Vec<u8>)> {
    vec![
        ("01 46 77", repeat(&[0x01, 0x46, 0x77], len)),
        ("noise", noise(len)),
        (
            "0F, 255-byte frames",
            repeat(&[0x01, 0x0F, 0x00, 0x00, 0x00, 0x08, 0xF6], len),
        ),
    ]
}

/// Pushes `flood`, lets the line fall silent, pushes a real frame; returns the seconds the flood
/// took, and checks the buffer stayed bounded and the frame came out.
fn run(mut reader: FrameReader, flood: &[u8], piece: usize, frame: &[u8]) -> f64 {
    let start = Instant::now();
    for chunk in flood.chunks(piece) {
        reader.push(chunk);
        assert!(reader.pending().len() < MAX_FRAME_LEN);
    }
    let seconds = start.elapsed().as_secs_f64();
    // A header in the flood may announce a frame longer than what follows: only silence ends it.
    reader.end_of_silence();
    assert_eq!(
        reader.push(frame),
        vec![frame.to_vec()],
        "the frame after the flood"
    );
    seconds
}

/// A reader to measure: its name, how to make one, and a frame it must find after a flood.
type Side<'a> = (&'static str, fn() -> FrameReader, &'a [u8]);

fn main() {
    let read_di = Request::ReadBits(BitArea::Inputs);
    let request = read_di.encode(1);
    let answer = encode_response(1, &Response::Bits(0xDF));
    let readers: [Side; 3] = [
        ("requests", FrameReader::for_requests, &request),
        ("answers", FrameReader::for_answers, &answer),
        (
            "answer to 01 01",
            || {
                let mut r = FrameReader::for_answers();
                r.expect_answer(1, &Request::ReadBits(BitArea::Inputs));
                r
            },
            &answer,
        ),
    ];
    let sizes: &[usize] = if BenchArgs::from_env().full {
        &SIZES
    } else {
        &SMOKE
    };
    println!("ns per byte (flat across sizes = linear)");
    for (side, reader, frame) in readers {
        for piece in [usize::MAX, 16] {
            let how = if piece == usize::MAX {
                "one push"
            } else {
                "16-byte pushes"
            };
            for (name, _) in floods(1) {
                let mut line = format!("{side:>15}  {how:<14}  {name:<20}");
                for &kib in sizes {
                    let flood = floods(kib * 1024)
                        .into_iter()
                        .find(|(n, _)| *n == name)
                        .map(|(_, f)| f)
                        .unwrap_or_default();
                    let seconds = run(reader(), &flood, piece.min(flood.len().max(1)), frame);
                    let per_byte = seconds * 1e9 / flood.len() as f64;
                    line.push_str(&format!("  {kib:>3} KiB {per_byte:>7.1}"));
                }
                println!("{line}");
            }
        }
    }
}
