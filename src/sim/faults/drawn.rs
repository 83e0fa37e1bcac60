//! Faults drawn by chance for each answer, for the pty simulator (`rigscript sim`): the words
//! are the vocabulary's (`sim::faults`), each at a probability per answer.

use std::time::Duration;

/// Faults to inject into answers, each drawn independently per answer.
#[derive(Debug, Clone, Default)]
pub struct Drawn {
    /// Probability (0..=1) that an answer is dropped.
    pub drop: f64,
    /// Probability (0..=1) that one bit of one byte of an answer is flipped.
    pub flip: f64,
    /// How late every answer is given (the module answering one request at a time).
    pub late: Duration,
    /// Seed for the random draws, for repeatable runs.
    pub seed: Option<u64>,
}

impl Drawn {
    /// The random source the draws come from: seeded when a seed is given.
    pub fn rng(&self) -> fastrand::Rng {
        self.seed
            .map_or_else(fastrand::Rng::new, fastrand::Rng::with_seed)
    }

    /// `answer` as the draws make it: `None` when dropped.
    pub fn apply(&self, rng: &mut fastrand::Rng, mut answer: Vec<u8>) -> Option<Vec<u8>> {
        if self.drop > 0.0 && rng.f64() < self.drop {
            return None;
        }
        if self.flip > 0.0 && rng.f64() < self.flip {
            let at = rng.usize(..answer.len());
            if let Some(byte) = answer.get_mut(at) {
                *byte ^= 1 << rng.u8(..8);
            }
        }
        Some(answer)
    }
}
